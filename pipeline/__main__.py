"""``python -m pipeline``: the ``bnptrack`` command line."""

from pipeline.cli import main

if __name__ == "__main__":
    main(prog_name="bnptrack")
