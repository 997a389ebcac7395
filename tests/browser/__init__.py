"""Browser tests of the served dashboard (``tests/browser/conftest.py``; marker ``browser``)."""
