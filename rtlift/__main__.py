import sys

from rtlift.app.cli import main

sys.exit(main())
