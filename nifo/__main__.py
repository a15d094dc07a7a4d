import sys

try:
    from nifo.cli import main

    code = main()
except KeyboardInterrupt:   # Ctrl-C (or SIGINT) while starting up, before a command runs: nothing was written
    print("nifo: interrupted while starting; nothing was written", file=sys.stderr)
    code = 130
sys.exit(code)
