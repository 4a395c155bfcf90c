"""``python -m aobake.compare``: the same command as ``aobake compare``."""

from aobake.compare import main

if __name__ == "__main__":
    main()
