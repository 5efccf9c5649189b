"""Export the plant (paper Eq. 1, 5-7 with the disturbance models, or any arm model) as an FMU.

:func:`export_plant` generates the plant's maths as C from the same kernels
the Python blocks and the compiled engine run (:mod:`fmu.generated`, written
to ``plant_generated.h``), writes the C model with this export's parameters
as start values, compiles it with the system C compiler and zips

* ``modelDescription.xml`` (FMI 2.0 or 3.0, Model Exchange and Co-Simulation),
* ``binaries/<platform>/dobkit_plant.so`` (``linux64`` for FMI 2,
  ``x86_64-linux`` for FMI 3),
* ``sources/``: every C file and header needed to rebuild the binary (the
  model, the FMI layer and the entry points it shares with the controller FMU,
  :func:`fmu.build.shared_layer_files`), the
  standard FMI headers (with their BSD notice), ``BUILD.txt`` with the compile
  command and, for FMI 3, ``buildDescription.xml``;
* for an arm other than the paper's, ``resources/dobkit_arm.json``: its joints
  and geometry (:mod:`fmu.arm_record`), from which ``dobkit fmu check``
  rebuilds the arm to compare the FMU with.

The GUID / instantiationToken is a hash of the C sources, the variable table
and the FMI version: the same export gives the same token, any change gives a
new one.  The binary refuses to instantiate under any other token.

Co-Simulation integrates with the classical fourth-order Runge-Kutta method,
``n_substeps`` equal steps per communication step; its global error falls as
``(h / n_substeps)^4``.  The inputs are held over the step, or follow the
slopes the importer sets (FMI 2 ``fmi2SetRealInputDerivatives``) or the
values it gives when asked during the step (FMI 3 intermediate update); the
outputs' first derivatives are available (see :mod:`fmu.coupling`).

Joint ranges: each joint position ``q[i]`` carries its joint's range as the
FMI ``min`` / ``max`` attributes (rad, m; from the arm's
:class:`~blocks.model.joints.JointSpace`: the RRPR's slide ``d3`` 0 to 0.48 m, a URDF
joint's ``<limit lower upper>``, none for a continuous joint), and the model
enforces them with an end stop at each finite end: a critically damped
spring-damper (``stop_stiffness[i]``, ``stop_damping[i]``, start values from
the arm's inertia for a 200 rad/s stop, :mod:`fmu.end_stops`) that adds to
the joint's force beyond the range and is exactly zero inside it.  With zero
torque (the disturbance models off) the RRPR's slide falls onto its stop and
rests 0.245 mm beyond 0.48 m (``(m3 + m4) g / k``), where it fell without
bound before.
"""
from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

from blocks.model.arm import ArmModel
from blocks.model.disturbances import DisturbanceSpec
from blocks.scenarios.scenario import default_arm

from .arm_record import ARM_RECORD, arm_record
from .build import instantiation_token, platform_folder, rebuild_command, shared_layer_files
from .end_stops import end_stops as arm_end_stops
from .generated import GENERATED_HEADER, arm_disturbance, plant_c
from .modeldescription import build_description_xml, model_description_xml
from .package import package_fmu
from .variables import config_header, plant_variables

__all__ = ["export_plant", "MODEL_IDENTIFIER", "plant_source_files"]

MODEL_IDENTIFIER = "dobkit_plant"
_MODEL_SOURCES = ("plant_model.c", "plant_instance.c", "plant_state.c")
_MODEL_HEADERS = ("plant_model.h", "plant_instance.h", "plant_state.h")
_TOKEN_PLACEHOLDER = "{00000000-0000-0000-0000-000000000000}"


def plant_source_files(fmi_version: int) -> list[str]:
    """Names of the C files compiled for an FMI version (all under ``fmu/c``)."""
    return list(_MODEL_SOURCES) + [f"fmi{fmi_version}_plant.c"] + shared_layer_files(fmi_version)[0]


def _read_c(name: str) -> str:
    return (resources.files("fmu") / "c" / name).read_text(encoding="utf-8")


def _check_args(fmi_version, substeps) -> None:
    if fmi_version not in (2, 3) or isinstance(fmi_version, bool):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or not 1 <= substeps <= 1_000_000:
        raise ValueError(f"substeps must be an integer from 1 to 1000000 (RK4 steps per co-simulation step), "
                         f"got {substeps!r}")


def _joint_vector(value, name: str, n: int):
    """None, or n finite floats (one per joint); raises ValueError naming the argument otherwise."""
    if value is None:
        return None
    try:
        items = [float(v) for v in value]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} finite numbers (one per joint), got {value!r}") from None
    if len(items) != n or not all(math.isfinite(v) for v in items):
        raise ValueError(f"{name} must be {n} finite numbers (one per joint), got {value!r}")
    return items



def _build_txt(fmi_version: int, sources: list[str]) -> str:
    lib, cmd = rebuild_command(MODEL_IDENTIFIER, sources)
    return (f"dobkit plant FMU (FMI {fmi_version}.0): rebuild the binary from this folder with any C99 compiler\n\n"
            f"    {cmd}\n\n"
            f"and place {lib} in binaries/{platform_folder(fmi_version)}/ of the FMU.\n"
            "plant_config.h holds this export's value references, start values and instantiation token;\n"
            "plant_generated.h the plant's maths, generated from dobkit's kernels for this arm.\n"
            "The fmi*.h headers are the standard FMI headers (2-clause BSD, Modelica Association Project FMI).\n")


def export_plant(path, params: ArmModel | None = None, disturbance: DisturbanceSpec | None = None,
                 fmi_version: int = 2, substeps: int = 4, cc: str | None = None, q0=None, dq0=None,
                 force: bool = False, end_stops: bool = True) -> Path:
    """Export the plant as an FMU (Model Exchange and Co-Simulation in one archive).

    Parameters
    ----------
    path : str or pathlib.Path
        Where to write the ``.fmu`` file (its folder must exist).  An existing
        file is refused unless ``force`` is true.
    params : blocks.model.arm.ArmModel, optional
        The true arm: the default scenario's by default (:func:`blocks.scenarios.scenario.default_arm`, the paper's arm
        with Table 1), whose named parameters become the FMU's parameters (``m1`` ... ``d4``, with ``k1..k5``
        derived from them), so changing one at simulation time works; an arm without named parameters (a
        URDF arm of :func:`blocks.model.urdf.load_urdf_arm`) has its geometry fixed in the C.
    disturbance : DisturbanceSpec, optional
        Disturbance models switched on (``disturbance_paper``,
        ``disturbance_friction``, ``disturbance_tissue``) and their parameters;
        default: the paper's Eq. 4 (for another arm: every model off, zero
        amplitudes, all settable as start values, and the skin plane through the
        tool point at ``q0``).
    fmi_version : {2, 3}
        FMI 2.0 or FMI 3.0.
    substeps : int
        Start value of ``n_substeps``: classical RK4 steps per Co-Simulation
        communication step (>= 1).
    cc : str, optional
        C compiler command; default ``$CC``, else ``cc``/``gcc``/``clang``.
    q0, dq0 : n floats, optional
        Start values of the joint positions (rad, m) and velocities (rad/s, m/s).
        By default the arm starts at rest in its :meth:`~blocks.model.arm.ArmModel.rest_pose`: the paper's arm in
        the regular pose ``theta2 = pi/2``, ``d3 = 0.24 m`` (not at the singular ``theta2 = 0``), a chain at
        ``q = 0`` or, for a joint whose range excludes 0, at the middle of its range.  Every ``q0`` must lie in
        the joint ranges.
    force : bool
        Replace an existing file at ``path`` (as ``dobkit fmu export --force``).
    end_stops : bool
        Enforce the joint ranges with end stops (default).  The ranges are the
        ``min`` / ``max`` of ``q[i]`` either way; each bounded joint ``i`` gets
        the parameters ``stop_stiffness[i]`` (N m/rad, N/m) and
        ``stop_damping[i]`` (N m s/rad, N s/m), set from the arm's smallest
        effective inertia ``m_i`` over its range for a natural frequency
        ``w = 200 rad/s`` and critical damping: ``k = m_i w^2``,
        ``c = 2 m_i w`` (stable for RK4 sub-steps up to 13.9 ms; see
        :mod:`fmu.end_stops`).  Inside the ranges the FMU gives the same
        numbers, bit for bit, as one exported with ``end_stops=False``.

    Returns
    -------
    pathlib.Path
        The written FMU.

    Raises
    ------
    FMUBuildError
        If no C compiler is available or compilation fails.
    ValueError
        On an invalid ``fmi_version``, ``substeps``, ``q0`` or ``dq0`` (a ``q0`` outside a joint's range).
    FileExistsError
        If ``path`` exists and ``force`` is false (nothing is compiled).

    Examples
    --------
    >>> from fmu import export_plant, load
    >>> path = export_plant("plant.fmu", fmi_version=3)
    >>> path.name
    'plant.fmu'
    >>> plant = load(path)                      # Model Exchange, as a python-control block
    >>> plant.nstates
    8
    >>> plant.fmu.close()
    """
    _check_args(fmi_version, substeps)
    params = default_arm() if params is None else params
    n = params.joints.count
    q0, dq0 = _joint_vector(q0, "q0", n), _joint_vector(dq0, "dq0", n)
    if q0 is None:
        q0 = params.rest_pose()
    outside = params.joints.outside_limits(q0)
    if outside:
        raise ValueError(f"q0 = {q0}: {outside}; give a start pose inside the joint ranges")
    disturbance = arm_disturbance(params, disturbance, q0)
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path {str(path)!r} is a folder; give the path of the .fmu file to write")
    if path.exists() and not force:
        raise FileExistsError(f"path {str(path)!r} exists; refusing to overwrite it (pass force=True to replace it)")

    stops = arm_end_stops(params, q0) if end_stops else []
    variables = plant_variables(params, disturbance, substeps, q0=q0, dq0=dq0, stops=stops)
    sources = plant_source_files(fmi_version)
    headers = list(_MODEL_HEADERS) + shared_layer_files(fmi_version)[1]
    c_texts = {name: _read_c(name) for name in headers + sources}
    reals = [v for v in variables if v.c_name is not None]
    generated = plant_c(params, disturbance, [v.name for v in reals], {v.name: v.start for v in reals})
    c_texts[GENERATED_HEADER] = generated.text
    description = f"{params.description()} with external disturbance models; exported by dobkit"
    tool = "fmu.export"

    def xml_for(token: str) -> str:
        return model_description_xml(variables, fmi_version, MODEL_IDENTIFIER, token, sources, description, tool)

    record = arm_record(params)
    token = instantiation_token("plant", fmi_version, [c_texts[n] for n in sorted(c_texts)]
                   + [config_header(variables, _TOKEN_PLACEHOLDER), xml_for(_TOKEN_PLACEHOLDER), record or ""])
    header = config_header(variables, token)
    xml = xml_for(token)

    texts = dict(c_texts, **{"plant_config.h": header})
    extra = {"sources/BUILD.txt": _build_txt(fmi_version, sources)}
    if record is not None:
        extra[ARM_RECORD] = record        # the arm for ``dobkit fmu check`` (its numbers are constants in the C)
    if fmi_version == 3:
        extra["sources/buildDescription.xml"] = build_description_xml(MODEL_IDENTIFIER, sources)
    package_fmu(path, xml, texts, sources, MODEL_IDENTIFIER, fmi_version, extra_files=extra, cc=cc,
                replace=force)
    return path
