"""Entry point of the frozen participant app (PyInstaller): the ``cgvq-study`` command line."""

import multiprocessing
import sys

from study_app.cli import main

if __name__ == "__main__":
    multiprocessing.freeze_support()
    sys.exit(main())
