"""``python -m sfmnet <command> [hydra overrides]``."""

from sfmnet.cli import main

if __name__ == "__main__":
    main()
