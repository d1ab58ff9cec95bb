"""crokf: co-rotational reduced-order Kalman filter FEM from Python.

``compile`` turns a scene file into a model (in process, through the Rust compiler library),
``Model.load`` reads and verifies a ``.crokf`` model file, ``Estimator`` runs the runtime's
steady-state Kalman filter step by step or over whole NumPy histories (``Estimator.run``).
Units: metres, newtons, seconds, radians. Errors are ``CrokfError`` subclasses carrying the
compiler's or the runtime's message: ``ChannelError`` (also a ``KeyError``) for a channel,
sensor, node set or phase the model does not have, ``InputError`` (also a ``TypeError``) for a
value that is not a real number (complex, string, boolean). ``identify`` finds the force σ of
a co-rotational model's estimated loads from a recording (``IdentifyError`` on a refusal).
``training_cases``, ``run_training_case`` and ``training_case_status`` expose the tier's
training runs as independent cases and check a cache of them; ``crokf.distributed`` runs them on Dask (``python -m crokf.distributed``).
"""

from ._crokf import (
    ChannelError,
    CompileError,
    CrokfError,
    Estimator,
    EstimatorError,
    IdentifyError,
    InputError,
    Model,
    ModelFileError,
    __version__,
    compile,
    run_training_case,
    training_case_status,
    training_cases,
)
from ._crokf import identify as _identify


def identify(scene, model, measurements, inputs=None, out=None, **options):
    """Identify the force σ of ``model``'s estimated loads from a recording.

    ``scene``: the scene file the co-rotational model was compiled from; ``model``: its
    ``.crokf`` file; ``measurements`` and ``inputs``: ``crokf-run``'s CSV files (without
    ``inputs`` every input is 0: the loads withheld); ``out``: write a copy of the scene with
    each identified load's ``force_noise_std`` and, where the recording disagrees with the
    scene's, the tier's ``model_error_scale`` (in the scene's folder). ``options``: ``lags``
    (30), ``skip`` (50), ``fixed_point`` (False). Each value comes with an uncertainty: the
    standard error over 4 disjoint blocks of the recording after ``skip``.

    Returns a dict: ``loads`` (per estimated load: ``name``, ``scene_sigma``, ``stated``,
    ``filter_sigma``, ``value``, ``uncertainty``, ``blocks``, ``excited``, ``rate``),
    ``model_error_factor`` (``value``, ``uncertainty``, ``blocks``, ``scene_factor``,
    ``filter_factor``, ``changed``; None without a measured model error),
    ``markers_factor`` (``value``, ``uncertainty``, ``blocks``: the check, within [0.8, 1.25]),
    ``steps``, ``samples``, ``lags``, ``skip``, ``blocks``, ``block_bounds``,
    ``relative_residual``, ``switches``, ``report`` (the command's text) and ``written``.
    Raises ``IdentifyError`` (a ``CrokfError``) on a refusal; nothing is written then.
    """
    return _identify(scene, model, measurements, inputs, out, **options)

__all__ = [
    "ChannelError",
    "CompileError",
    "CrokfError",
    "Estimator",
    "EstimatorError",
    "IdentifyError",
    "InputError",
    "Model",
    "ModelFileError",
    "__version__",
    "compile",
    "identify",
    "run_training_case",
    "training_case_status",
    "training_cases",
]
