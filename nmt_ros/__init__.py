"""nmt_ros: neuromusculoskeletal tracking (Seth & Pandy 2007) with a ROS 2 node graph.

Layers, lowest first (imports point downward only; ``test/test_layers.py`` checks it):
``model`` (and ``osim`` beside it), ``records`` and ``topics`` -> ``tracking`` ->
``msg_adapters`` (a sibling package) -> ``io`` -> ``study`` -> ``nodes`` -> ``cli``.
model, tracking and study run without ROS. The README's "Layout" says what lives where.
"""

__version__ = '0.1.0'
