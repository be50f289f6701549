import sys

from services.scorer import main

sys.exit(main())
