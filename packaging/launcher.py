"""Entry point of the desktop bundle: the same as the ``motion-composer`` console command."""
import multiprocessing
import sys

from motion_composer.app.cli import main

if __name__ == "__main__":
    multiprocessing.freeze_support()
    sys.exit(main())
