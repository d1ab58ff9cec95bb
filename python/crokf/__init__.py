"""crokf: co-rotational reduced-order Kalman filter FEM from Python.

``compile`` turns a scene file into a model (in process, through the Rust compiler library),
``Model.load`` reads and verifies a ``.crokf`` model file, ``Estimator`` runs the runtime's
steady-state Kalman filter step by step or over whole NumPy histories (``Estimator.run``).
Units: metres, newtons, seconds, radians. Errors are ``CrokfError`` subclasses carrying the
compiler's or the runtime's message: ``ChannelError`` (also a ``KeyError``) for a channel,
sensor, node set or phase the model does not have, ``InputError`` (also a ``TypeError``) for a
value that is not a real number (complex, string, boolean).
"""

from ._crokf import (
    ChannelError,
    CompileError,
    CrokfError,
    Estimator,
    EstimatorError,
    InputError,
    Model,
    ModelFileError,
    __version__,
    compile,
)

__all__ = [
    "ChannelError",
    "CompileError",
    "CrokfError",
    "Estimator",
    "EstimatorError",
    "InputError",
    "Model",
    "ModelFileError",
    "__version__",
    "compile",
]
