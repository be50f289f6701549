import sys

from services.plant import main

sys.exit(main())
