"""easyhec's stand-in for ament_index_python, put on the xacro tool's PYTHONPATH by easyhec.

PyPI's xacro answers $(find NAME) only through ament_index_python, which is not on PyPI;
this package answers it from the search easyhec made (docs/config.md, package_paths).
"""
from .packages import PackageNotFoundError, get_package_prefix, get_package_share_directory  # noqa: F401
