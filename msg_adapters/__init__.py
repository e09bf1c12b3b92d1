"""Arrays <-> ROS 2 messages: the only place where the two meet.

Modules: ``stamps`` (int ns / float s <-> builtin_interfaces/Time), ``joint_state``,
``wrench``, ``planar``, ``diagnostics``, ``clock``, ``cdr_header`` and ``validation`` (the
``ValueError`` checks); ``series`` (the stacked-array containers, ``JointStateSeries`` /
``WrenchSeries``, that the batch helpers return and accept) and ``cdr_arrays`` (serialised
messages of a whole bag topic decoded straight into those containers). Nothing here imports
``nmt_ros``: ``nmt_ros.io`` builds on this package, never the reverse.
Read ``msg_adapters.joint_state`` for why unused JointState arrays are NaN-filled.
"""
