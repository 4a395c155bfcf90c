"""``python -m aobake``: same as the ``aobake`` command."""

from aobake.cli import main

if __name__ == "__main__":
    main()
