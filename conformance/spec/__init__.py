"""The spec sets as data: commands, dialects, firmware versions, safety classes, what
changed between two spec sets.

``commands``: a spec set (``specs/fairino-*/commands.json``) as :class:`~.commands.SpecSet`;
``dialects``: the field's recorded forms; ``firmware``: versions and the spec set that fits;
``knowledge``: per-command meaning beyond the tables; ``safety``: what each command may do
to a robot; ``diff``: two spec sets compared (``specs diff``).
"""
