"""The digital twin: the emulated controller's model (no sockets).

``controller``: the controller's state and its answer to each request; ``kinematics``:
the arms' forward and inverse kinematics and joint limits; ``faults``: faults injected
to test the kit; ``actions``: what a command does to the model.  The official SDKs'
own ports read the same model: ``xmlrpc`` (20003: a call as its command, the reply in
the SDKs' shape), ``cnde`` (20005: one client's configured state stream).
"""
