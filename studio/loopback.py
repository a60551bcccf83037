"""The address the servers listen on by default (this machine only) and the names it goes by;
this module imports nothing, so that the command line offers it without loading asyncio."""

LOOPBACK = "127.0.0.1"
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
