import sys

from rtlift.cli import main

sys.exit(main())
