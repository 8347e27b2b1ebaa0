"""``python -m bt_pipeline`` is the ``bt`` command."""

from bt_pipeline.cli import main

if __name__ == "__main__":
    main()
