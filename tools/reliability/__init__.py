"""Shared parts of tools/loadtest.py and tools/crash_test.py: the server process, the
requests they send, /proc sampling and the tables they print (docs/reliability.md)."""
