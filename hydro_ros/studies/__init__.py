"""The thesis's studies over the science layers and the workflows (no ROS): FDI evaluation and parity fit, the GSA, MEMS,
the DP comparison and savings map, hidden effects, the crane's monitoring, and the plants written apart from the
models (``independent_plant``, ``independent_arm``). Each module is imported on its own (``hydro_ros.studies.gsa``):
they pull in heavy optional libraries (matplotlib, SALib)."""
