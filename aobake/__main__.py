"""``python -m aobake``: same as the ``aobake`` command."""

from aobake.cli import entry

if __name__ == "__main__":
    entry()
