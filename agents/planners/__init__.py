"""Ports of the three 2022 Driving SMARTS planners benchmarked in the SMARTS 2.0 paper.

- ``tf``: hierarchical rules (speed, lane, direction) with a stop/move veto (rules + a small
  behaviour-cloning net);
- ``vcr``: a Bezier waypoint follower whose speed is set by a collision classifier over rasters;
- ``aid``: a Frenet sampling planner over a motion predictor (constant velocity or a learned
  factorised Transformer).

They read only the observation (``smarts.sensors.observation``) and act in RelativeTargetPose.
Shared parts: ego-frame and odometry helpers (``frames``), geometry (``geometry``), the path helper
(``paths``), the neighbour tracker (``tracker``) and per-agent state across batched calls
(``agent_state``).
"""
