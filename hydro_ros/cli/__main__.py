import sys

from hydro_ros.cli import main

sys.exit(main())
