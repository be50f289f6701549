import sys

from hydrowatch.cli import main

sys.exit(main())
