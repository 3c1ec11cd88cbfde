"""Kinematics of the FAIRINO FR arms: forward, inverse, joint limits, from cited vendor data.

``robot("FR5")`` (the default) gives a :class:`Robot` whose ``forward``,
``inverse``, ``has_solution`` and ``within_limits`` answer the protocol's
GetForwardKin, GetInverseKin/GetInverseKinRef and GetInverseKinHasSolution, and
whose limits refuse out-of-range targets.  ``robots.ROBOTS`` names the
models (``specs/fairino-robots.json``, read on first use).  Pure, sans-I/O apart from
loading that file once.

* :mod:`.pose` - the pose convention (mm; fixed-axis rx, ry, rz in degrees);
* :mod:`.chain` - standard DH forward kinematics and the Jacobian;
* :mod:`.limits` - joint limits and whole turns;
* :mod:`.ik` - the closed-form inverse and its configuration numbers;
* :mod:`.robots` - the data file and the :class:`Robot` API.
"""
