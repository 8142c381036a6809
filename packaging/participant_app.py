"""Entry point of the frozen participant app (PyInstaller): the ``cgvq-study`` command line."""

import multiprocessing
import sys

from cgvq_cli.study_cli import main

if __name__ == "__main__":
    multiprocessing.freeze_support()
    sys.exit(main())
