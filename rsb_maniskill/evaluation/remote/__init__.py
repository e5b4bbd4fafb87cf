"""Policies over the network, in openpi's websocket protocol: the client policy (``client.py``,
``rsb eval remote``), a server for any RSB policy (``server.py``, ``python -m
rsb_maniskill.evaluation.remote.server``) and the ``openpi-aloha`` preset (``openpi.py``). Needs the
``eval`` extra (websockets, msgpack), imported on first use."""
