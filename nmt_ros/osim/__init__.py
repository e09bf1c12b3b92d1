"""OpenSim bridge: path fitting, .osim export, cross-checks.

Modules here import ``opensim`` and must never import ``casadi`` (or anything that does,
such as ``nmt_ros.model.jumper``): the two libraries cannot share a process. Callers in
casadi processes run these modules as subprocesses (``python -m nmt_ros.osim.<module>``,
as ``nmt_ros.cli.export_osim`` and the cross-check tests do).
"""
