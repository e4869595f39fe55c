import sys

from ..core.errors import run_command
from .cli import PROG, main

sys.exit(run_command(main, PROG))
