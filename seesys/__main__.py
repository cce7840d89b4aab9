import sys

from seesys_app.cli import main

sys.exit(main())
