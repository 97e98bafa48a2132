"""``python -m bnptrack``: the ``bnptrack`` command line."""

from bnptrack.pipeline.cli import main

if __name__ == "__main__":
    main(prog_name="bnptrack")
