"""slam2d live on a robot: ``slam2d ros METHOD`` runs a method as a ROS 1 node (:mod:`slam2d.ros.node`).

ROS 1 comes from the system (Debian's ``ros-core``, ``python3-rospy``, ``python3-tf2-ros`` and the
message packages), not from PyPI: :func:`import_rospy` finds it in the system's Python packages when
the virtual environment does not see them.
"""

from __future__ import annotations

import sys
from pathlib import Path

from slam2d.errors import Slam2dError

__all__ = ["import_rospy", "SYSTEM_PACKAGES", "ROS_PACKAGES"]

#: where Debian installs the ROS 1 Python packages
SYSTEM_PACKAGES = Path("/usr/lib/python3/dist-packages")
#: the Debian packages the node needs
ROS_PACKAGES = ("ros-core", "python3-rospy", "python3-tf2-ros", "python3-sensor-msgs", "python3-nav-msgs",
                "python3-geometry-msgs", "python3-std-srvs", "python3-diagnostic-msgs", "python3-tf2-msgs")


def import_rospy():
    """``rospy``, from this environment or else from the system's packages (appended: the venv's numpy wins)."""
    try:
        import rospy  # noqa: F401
    except ImportError:
        if SYSTEM_PACKAGES.is_dir() and str(SYSTEM_PACKAGES) not in sys.path:
            sys.path.append(str(SYSTEM_PACKAGES))
        try:
            import rospy  # noqa: F401
            import tf2_ros  # noqa: F401
        except ImportError as exc:
            raise Slam2dError(
                f"ROS 1 is not installed ({exc}): on Debian or Ubuntu, sudo apt-get install "
                + " ".join(ROS_PACKAGES)
            ) from None
    import rospy

    return rospy
