"""The live view: the graph's topics and the body scene over the Foxglove WebSocket protocol.

``server`` (the WebSocket server, foxglove-sdk), ``scene`` (the body as a Foxglove
SceneUpdate), ``bag_replay`` (a bag into the server without a graph). The ``viewer`` node
(``nmt_ros.nodes.viewer``) and ``nmt view`` / ``nmt launch --view`` drive them.
"""
from __future__ import annotations

#: The view server's defaults: loopback only, Foxglove's usual port.
DEFAULT_HOST = '127.0.0.1'
DEFAULT_PORT = 8765
