"""turning_force: cutting-force regulation for CNC lathes through the feedrate override."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version('turning_force')
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = '0.0.0+unknown'
