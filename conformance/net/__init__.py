"""The only place with sockets: the client, the emulator, the proxy, the replay server.

The emulator serves the text port itself and, from the same model, the state port
(``emulator_state``; also the SDKs' realtime port 20004) and the SDKs' XML-RPC
(``xmlrpc_port``, 20003) and CNDE (``cnde_port``, 20005) ports, on the base ``port``.

Addresses are read and written in one place, :mod:`conformance.net.addresses`.
"""
