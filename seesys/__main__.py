import sys

from seesys.cli import main

sys.exit(main())
