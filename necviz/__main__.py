import sys

from necviz.commands.cli import main

sys.exit(main())
