"""ltlnav envs: robots (dynamics) and rewards as Gymnasium environments.

Importing the package stays light (no torch, no pybullet) so that the ``robot:`` section of a
mission (``envs.spec``) can be validated anywhere.
"""

from envs.factory import make_env  # importing the factory registers ltlnav/Nav-v0

__all__ = ["make_env"]
