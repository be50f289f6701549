import sys

from services.replay import main

sys.exit(main())
