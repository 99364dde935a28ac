"""sanav-mj: quadtree safe-area MPC (SA-MPC) navigation of a differential-drive robot in MuJoCo.

The data flow is one-way (see docs/ and the design contract):

    scene -> mapping -> planning -> control -> sim -> eval / record / cli
"""

__version__ = "0.1.0"
