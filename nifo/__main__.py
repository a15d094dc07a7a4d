import sys

from nifo.cli import main

sys.exit(main())
