"""loggrasp's simulator twin: piles, the pybullet world, renders, grapple and grasp trials.

The bottom layer of loggrasp: nothing here imports :mod:`planner`, :mod:`reconstruct` or
:mod:`field`. Heavy libraries (pybullet, OpenCV) are imported inside the functions that need them.
"""

__version__ = "0.1.0"
