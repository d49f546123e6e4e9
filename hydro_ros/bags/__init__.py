"""Contract bags (contract section 2): ROS 2 bag directories with MCAP storage, no ROS needed; and the
sample aligner the live monitor shares with the bag reader."""

from hydro_ros.bags.align import SampleAligner, SampleLayout
from hydro_ros.bags.reader import BagData, BagError, read_bag
from hydro_ros.bags.writer import BagExistsError, ContractBagWriter

__all__ = ["BagData", "BagError", "BagExistsError", "ContractBagWriter", "SampleAligner", "SampleLayout", "read_bag"]
