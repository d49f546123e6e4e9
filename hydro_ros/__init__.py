"""hydro_ros: condition monitoring and energy-optimal motion for hydraulic manipulators.

Layers, each importing only from those before it: ``contract`` (names, sample types, the typed
machine config, the InputError family) <- ``safety`` (the safety core), ``bags``, ``can`` <- ``models``
<- ``sim``, ``fdi``, ``planning`` <- ``workflows`` (what ships: commissioning, the fleet view, the
discrepancy workflow, execution, plots), ``hmi`` <- ``studies`` (the thesis's) <- ``nodes`` <- ``demo``
<- ``cli``. Nothing below ``nodes`` imports rclpy (test/test_layers.py keeps it so).
"""

__version__ = "0.1.0"
