"""`python -m physdrape.cli ...` (e.g. under torchrun): the `physdrape` command."""

import sys

from physdrape.cli import main

sys.exit(main())
