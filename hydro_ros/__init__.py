"""hydro_ros: condition monitoring and energy-optimal motion for hydraulic manipulators.

The science lives in plain libraries (``models``, ``sim``, ``bags``) that never import rclpy;
``nodes`` wires them to ROS 2 and ``cli`` drives them offline.
"""

__version__ = "0.1.0"
