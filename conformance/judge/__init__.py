"""The one judge: what a frame, a stream or a state packet is worth.

``verdict``: outcomes, their severity and the one rule for what fails; ``requests``: a
request and a reply read against the spec tables; ``judge``: :class:`~.judge.Judge`, a
frame's verdict; ``stream``: CNT steps and reply pairing over a connection;
``sequence``: the order rules over a client's requests; ``state``: the state port's
problems.
"""
