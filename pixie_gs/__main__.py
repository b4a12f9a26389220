"""`python -m pixie_gs`: the `pixie` command. Ctrl-C while the modules are still importing exits 130
with one line, like an interrupt during a command (main() handles those)."""
import sys

try:
    from .cli.main import main
except KeyboardInterrupt:
    print("pixie: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
