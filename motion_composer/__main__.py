"""``python -m motion_composer``: the same as the ``motion-composer`` command."""
import sys

from app.cli import main

sys.exit(main())
