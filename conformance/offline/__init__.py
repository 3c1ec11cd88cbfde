"""Readings of a recording.  One engine reads, pairs, judges and blames a recording a window
at a time (``engine``); ``check``, ``info`` and ``export-parquet`` are its readings.
``exchanges`` gives the same rules over a recording read whole, for ``diff``, ``replay`` and
``export-pcap``; ``state_check`` reads the state port's stream again; ``client_mode`` judges a
live client (``serve``).
"""
