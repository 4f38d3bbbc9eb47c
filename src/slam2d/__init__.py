"""slam2d: 2D laser SLAM methods behind one Python interface, with honest evaluation."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("slam2d")
except PackageNotFoundError:  # running from a source tree without installing
    __version__ = "0+unknown"

__all__ = ["__version__"]
