"""Helpers of the test suite (issue 14): everything tests import that is not a fixture. Fixtures
stay in ``tests/conftest.py``. Importing this package imports nothing (``real_services`` must
import nothing but pytest: ``tests/test_real_service_skips.py`` loads it in an inner session)."""
