import sys

from services.web import main

sys.exit(main())
