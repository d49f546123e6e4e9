"""Contract bags (docs/interface.md section 2): ROS 2 bag directories with MCAP storage, no ROS needed (``reader``, ``writer``); and
the sample aligner the live monitor shares with the bag reader (``align``). Nothing is imported here: a node that only
aligns samples does not pay for rosbags' type stores at start."""
