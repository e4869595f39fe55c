import sys

from .cli import main
from .errors import run_command

sys.exit(run_command(main, "neurolens_addon.core"))
