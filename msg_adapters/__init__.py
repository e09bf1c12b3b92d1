"""Arrays <-> ROS 2 messages: the only place where the two meet.

Modules: ``stamps`` (int ns / float s <-> builtin_interfaces/Time), ``joint_state``,
``wrench``, ``diagnostics``, ``clock`` and ``validation`` (the ``ValueError`` checks).
Batch helpers return/accept ``nmt_ros.io.series.JointStateSeries`` / ``WrenchSeries``.
Read ``msg_adapters.joint_state`` for why unused JointState arrays are NaN-filled.
"""
