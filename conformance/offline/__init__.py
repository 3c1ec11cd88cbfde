"""Readings of a recording: ``check``, ``info``, ``diff``, ``replay``, the state port's
and a capture's checks, and the client mode's judge of a live client (``serve``).
"""
