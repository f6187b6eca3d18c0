import sys

from metraw.cli import main

sys.exit(main())
