import os
import signal

os.environ.setdefault("MPLBACKEND", "Agg")

# The Ctrl-C tests send SIGINT to the runs they start, as a user at a terminal would. A shell
# without job control starts background commands (`make test &`) with SIGINT ignored, and an
# ignored signal stays ignored in every child: those runs would never see the Ctrl-C. A handler
# of ours (not ignored) is reset to the default in each child, so the runs get SIGINT again.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(config, items):
    """Tests marked ``long`` first (in their order): pytest-xdist hands tests out in collection
    order, and a long test handed out last keeps one worker busy while the other idles."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
