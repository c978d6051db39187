import os

os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``long`` first (in their order): pytest-xdist hands tests out in collection
    order, and a long test handed out last keeps one worker busy while the other idles."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
