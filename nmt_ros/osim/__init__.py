"""OpenSim bridge: path fitting, .osim export, cross-checks.

Modules here import ``opensim`` and must never import ``casadi`` (or anything that does,
such as ``nmt_ros.model.jumper``): the two libraries cannot share a process. Callers in
casadi processes run these modules as subprocesses (see ``nmt_ros.osim.run``).
"""
