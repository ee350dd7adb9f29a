"""``python -m motion_composer``: the same as the ``motion-composer`` command."""
import sys

from motion_composer.app.cli import main

sys.exit(main())
