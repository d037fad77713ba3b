"""Helpers of the test suite (issue 14): everything tests import that is not a fixture. Fixtures
stay in ``tests/conftest.py``. Importing this package imports nothing (``real_services`` and
``extended`` are plugins that must import nothing but pytest: ``tests/project/test_run_summary.py``
loads them in inner sessions); ``results`` holds pipeline results made without the pipeline."""
