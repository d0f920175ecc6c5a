"""Package lookups for the xacro tool, answered from the packages.json easyhec writes beside
this file: {"found": {name: folder}, "ambiguous": {name: reason}, "looked_in": where}.
"""
import json
import os

_INDEX = None


class PackageNotFoundError(KeyError):
    """Raised for a package easyhec's search did not find (or found twice)."""

    def __str__(self):
        return str(self.args[0]) if self.args else ""


def _index():
    global _INDEX
    if _INDEX is None:
        here = os.path.dirname(os.path.abspath(__file__))
        with open(os.path.join(here, "packages.json"), encoding="utf-8") as f:
            _INDEX = json.load(f)
    return _INDEX


def get_package_share_directory(package_name, print_warning=True):
    index = _index()
    if package_name in index["ambiguous"]:
        raise PackageNotFoundError(index["ambiguous"][package_name])
    if package_name not in index["found"]:
        raise PackageNotFoundError(
            "package '%s' not found; looked in %s" % (package_name, index["looked_in"])
        )
    return index["found"][package_name]


def get_package_prefix(package_name):
    """The install prefix of PREFIX/share/NAME (a source-tree package's parent's parent)."""
    return os.path.dirname(os.path.dirname(get_package_share_directory(package_name)))
