"""`python -m pixie_gs`: the `pixie` command. Ctrl-C while the modules are still importing exits 130
with one line, like an interrupt during a command (main() handles those)."""
import sys

try:
    from .cli.main import main
except KeyboardInterrupt:
    import os

    print("pixie: interrupted", file=sys.stderr, flush=True)
    os._exit(130)  # not sys.exit: CPython 3.11 may end a `-m` process with SIGINT here (cli.main.exit_interrupted)

sys.exit(main())
