"""``python -m approxtree`` runs the command line."""

from approxtree.cli import run

if __name__ == "__main__":
    run()
