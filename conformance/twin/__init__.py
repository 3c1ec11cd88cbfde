"""The digital twin: the emulated controller's model (no sockets).

``controller``: the controller's state and its answer to each request; ``kinematics``:
the arms' forward and inverse kinematics and joint limits; ``faults``: faults injected
to test the kit; ``actions``: what a command does to the model.
"""
