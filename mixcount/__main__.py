import sys

from mixcount.cli import main

sys.exit(main())
