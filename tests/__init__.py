"""The test suite: one folder per part of the code (``pipeline``, ``fusion``, ``synth``,
``service``, ``bench``), ``e2e`` for runs across the whole stack, ``project`` for the repository as
a whole, and ``utils`` for the helpers tests import; ``conftest.py`` holds the fixtures only."""
