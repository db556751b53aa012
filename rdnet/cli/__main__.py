import sys

from rdnet.cli import main

sys.exit(main())
