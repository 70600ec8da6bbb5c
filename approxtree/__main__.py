"""``python -m approxtree`` runs the command line."""

from approxtree.cli import main

if __name__ == "__main__":
    main()
