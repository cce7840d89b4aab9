"""What the tests share, imported by name (``from testkit.deepsee import tiny_config``); the fixtures among it reach
every test through ``tests/conftest.py``, never by an import of the test module."""
