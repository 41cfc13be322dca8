"""`python -m imulink.cli`: the `imulink` command."""
import sys

from imulink.cli import main

sys.exit(main())
