"""Export a scenario's digital controller as a Co-Simulation FMU (FMI 2.0 or 3.0).

:func:`export_controller` writes the sampled controller of a scenario with a
``[controller]`` section -- the computed-torque law of Eq. 11 on the nominal
model, the disturbance observer's update (``euler`` or ``zoh``), the velocity
estimate (measured, or the low-passed difference of the encoder positions),
the encoders' quantization, the delay, the torque limit and the scenario's
reference trajectory -- as an FMU that any FMI 2 or 3 Co-Simulation master can
couple to a plant:

* inputs ``q[i]``, ``dq[i]`` (named like the plant FMU's outputs), outputs
  ``tau[i]`` (like its inputs) and ``d_hat[i]``; the outputs of tick ``k``
  are computed from the inputs set at ``t_k`` and declared as depending on
  them, so a Gauss-Seidel master (set ``q``, ``dq``; read ``tau``; step the
  plant with it) reproduces the monolithic sampled run of
  :func:`blocks.figure2.digital_loop.simulate_sampled`;
* one ``doStep`` is one sample: any communication step other than the
  sample period is refused, naming it;
* ``kp[i]``, ``kd[i]`` and ``Y[i]`` (``Y[i,j]`` for a full observer gain)
  are tunable parameters; ``sample_period`` and ``reference_end`` are
  constants.

The C of a tick is generated from the sampled-controller kernels through the
trace the compiled engine uses (:mod:`fmu.controller_tick`); the FMI layer
(``fmu/c/fmi2_controller.c``, ``fmi3_controller.c`` over one instance core,
``controller_core.c``, with the entry points it shares with the plant FMU in
``fmi2_common.c`` / ``fmi3_common.c``, see :func:`fmu.build.shared_layer_files`)
and the matrix exponential of the ``zoh`` update (``fmu/c/controller_expm.c``)
are fixed C.

The reference is a table, one row ``[q_ref; dq_ref; ddq_ref]`` per tick from
``t = 0`` to the scenario's ``simulation.t_final``, computed by the
trajectory block of the monolithic loop at the tick times (the laceration
path's inverse kinematics stays in Python).  Stepping past the table's end is
refused, naming ``reference_end``.  Measurement noise belongs to the plant
side and is refused here.
"""
from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

import numpy as np

from .build import instantiation_token, rebuild_command, shared_layer_files
from .controller_tick import TickCode, trace_tick
from .controller_variables import controller_description_xml, controller_variables
from .modeldescription import build_description_xml
from .package import package_fmu

__all__ = ["export_controller", "CONTROLLER_IDENTIFIER", "reference_table"]

CONTROLLER_IDENTIFIER = "dobkit_controller"
_FIXED_SOURCES = ("controller_core.c", "controller_expm.c")
_GENERATED_SOURCES = ("controller_tick.c", "controller_reference.c")
_HEADERS = ("controller_tick.h", "controller_core.h")
_TOKEN_PLACEHOLDER = "{00000000-0000-0000-0000-000000000000}"


def _read_c(name: str) -> str:
    return (resources.files("fmu") / "c" / name).read_text(encoding="utf-8")


def reference_table(loop, scenario) -> np.ndarray:
    """The reference at every tick, shape (ticks, 3 n): rows ``[q_ref; dq_ref; ddq_ref]`` at ``t_k = k Ts``.

    The ticks run from ``t = 0`` to the scenario's ``simulation.t_final``
    (as :meth:`blocks.engines.hybrid.HybridSystem.simulate` counts them); the rows come
    from the loop's ``trajectory`` block, evaluated as the monolithic run does.
    """
    from blocks.diagram.contract import contract_of
    block = {b.name: b for b in loop.syslist}["trajectory"]
    kernels = contract_of(block).kernels
    joints = scenario.robot.joints
    labels = list(block.output_labels)
    order = [labels.index(name) for prefix in ("q_ref", "dq_ref", "ddq_ref") for name in joints.signal_names(prefix)]
    period = loop.base_period
    ticks = int(math.floor(scenario.simulation.t_final / period * (1 + 1e-12))) + 1
    empty = np.zeros(0)
    rows = np.empty((ticks, 3 * joints.count))
    for k in range(ticks):
        y = np.ravel(kernels.output(k * period, empty, empty, *kernels.params))
        rows[k] = y[order]
    return rows


def _c_array(name: str, values) -> str:
    items = [repr(float(v)) for v in np.ravel(values)]
    lines = [", ".join(items[i:i + 6]) for i in range(0, len(items), 6)]
    return f"const double {name}[{max(len(items), 1)}] = {{\n    " + ",\n    ".join(lines or ["0.0"]) + "\n};\n"


def _config_header(code: TickCode, variables, token: str, period: float, ticks: int) -> str:
    by_name = {v.name: v for v in variables}
    n = code.n
    tunable = [v for v in variables if v.variability == "tunable"]
    theta_index = code.gains["kp"] + code.gains["kd"] + code.gains["Y"]
    if len(tunable) != len(theta_index):
        raise AssertionError("every tunable parameter needs its place in theta")
    theta0 = ", ".join(repr(float(v)) if math.isfinite(v) else ("INFINITY" if v > 0 else "(-INFINITY)")
                       for v in code.theta)
    lines = [
        "/* controller_config.h: written by fmu.controller_export for one export; do not edit. */",
        "#ifndef DOBKIT_CONTROLLER_CONFIG_H", "#define DOBKIT_CONTROLLER_CONFIG_H", "",
        f'#define CTRL_TOKEN "{token}"',
        f"#define CTRL_N {n}", f"#define CTRL_NX {code.nx}", f"#define CTRL_NTHETA {len(code.theta)}",
        f"#define CTRL_ZOH {int(code.zoh)}",
        f"#define CTRL_BUF_START {code.buffer.start}", f"#define CTRL_BUF_LEN {code.buffer.stop - code.buffer.start}",
        f"#define CTRL_PERIOD {period!r}", f"#define CTRL_NTICKS {ticks}L",
        f"#define CTRL_REFERENCE_END {(ticks - 1) * period!r}", "",
        f"#define VR_Q {by_name['q[0]'].vr}", f"#define VR_DQ {by_name['dq[0]'].vr}",
        f"#define VR_TAU {by_name['tau[0]'].vr}", f"#define VR_D_HAT {by_name['d_hat[0]'].vr}",
        f"#define VR_PARAM {tunable[0].vr}", f"#define N_TUNABLE {len(tunable)}",
        f"#define VR_SAMPLE_PERIOD {by_name['sample_period'].vr}",
        f"#define VR_REFERENCE_END {by_name['reference_end'].vr}", f"#define VR_TIME {by_name['time'].vr}", "",
        "/* the place in theta of each tunable parameter, in value-reference order */",
        "#define CTRL_TUNABLE_THETA {" + ", ".join(str(i) for i in theta_index) + "}",
        "#define CTRL_TUNABLE_NAMES {" + ", ".join(f'"{v.name}"' for v in tunable) + "}",
        "#define CTRL_THETA0 {" + theta0 + "}",
        "", "#endif", "",
    ]
    return "\n".join(lines)



def _build_txt(fmi_version: int, sources: list[str]) -> str:
    lib, cmd = rebuild_command(CONTROLLER_IDENTIFIER, sources)
    return (f"dobkit controller FMU (FMI {fmi_version}.0 Co-Simulation): rebuild the binary from this folder "
            f"with any C99 compiler\n\n    {cmd}\n\nand place {lib} in binaries/<platform>/ of the FMU.\n"
            "controller_tick.c is generated from dobkit's sampled-controller kernels, controller_reference.c holds\n"
            "the reference table and controller_config.h this export's value references, gains and token.\n"
            f"The fmi{fmi_version}*.h headers are the standard FMI headers (2-clause BSD, Modelica Association "
            "Project FMI).\n")


def _check_scenario(s) -> None:
    from blocks.diagram.digital import DigitalController
    if not isinstance(s.controller, DigitalController):
        raise ValueError(f"scenario '{s.name}' has no [controller] section: the controller FMU holds a sampled "
                         "(digital) controller; add [controller] with sample_rate (Hz), or use a scenario such as "
                         "'paper-digital'")
    if s.noise is not None:
        raise ValueError(f"scenario '{s.name}' has a [noise] section: measurement noise belongs to the plant side "
                         "of a co-simulation, not to the controller FMU; remove [noise] to export the controller")


def export_controller(path, scenario, fmi_version: int = 2, cc: str | None = None, force: bool = False) -> Path:
    """Export the sampled controller of a scenario as a Co-Simulation FMU.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.fmu`` file to write (its folder must exist); an existing file is refused unless ``force``.
    scenario : str, pathlib.Path or blocks.scenarios.scenario.Scenario
        A scenario with a ``[controller]`` section (built-in name, file or object), e.g. ``"paper-digital"``.
    fmi_version : {2, 3}
        FMI 2.0 or 3.0 (Co-Simulation in both).
    cc : str, optional
        C compiler command; default ``$CC``, else ``cc``/``gcc``/``clang``.
    force : bool
        Replace an existing file at ``path``.

    Returns
    -------
    pathlib.Path
        The written FMU.

    Raises
    ------
    ValueError
        A scenario without ``[controller]`` or with ``[noise]``, or ``fmi_version`` other than 2 or 3.
    FileExistsError
        If ``path`` exists and ``force`` is false (nothing is compiled).
    fmu.errors.FMUBuildError
        If no C compiler is available or compilation fails.

    Examples
    --------
    >>> import blocks
    >>> from fmu.controller_export import export_controller
    >>> s = blocks.load_scenario("paper-digital").with_changes({"simulation.t_final": 1.0})
    >>> export_controller("controller.fmu", s).name     # inputs q[i], dq[i]; outputs tau[i], d_hat[i]
    'controller.fmu'
    """
    from blocks.figure2.sampled_blocks import sampled_loop
    from blocks.scenarios.scenario import Scenario, load_scenario
    if isinstance(fmi_version, bool) or fmi_version not in (2, 3):
        raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    s = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    _check_scenario(s)
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path {str(path)!r} is a folder; give the path of the .fmu file to write")
    if path.exists() and not force:
        raise FileExistsError(f"path {str(path)!r} exists; refusing to overwrite it (pass force=True to replace it)")

    loop = sampled_loop(s, observer=True)
    code = trace_tick(loop, s)
    period = s.controller.period
    table = reference_table(loop, s)
    ticks = table.shape[0]
    theta = code.theta
    variables = controller_variables(s.robot.joints.kinds, theta[code.gains["kp"]], theta[code.gains["kd"]],
                                     theta[code.gains["Y"]], code.y_full, period, (ticks - 1) * period)
    shared_sources, shared_headers = shared_layer_files(fmi_version)
    fixed = [f"fmi{fmi_version}_controller.c"] + list(_FIXED_SOURCES) + shared_sources
    sources = fixed + list(_GENERATED_SOURCES)
    texts = {name: _read_c(name) for name in fixed + list(_HEADERS) + shared_headers}
    texts["controller_tick.c"] = code.source
    texts["controller_reference.c"] = ("/* controller_reference.c: the reference [q_ref; dq_ref; ddq_ref] at each "
                                       f"tick of {period!r} s; written by fmu.controller_export. */\n"
                                       + _c_array("CTRL_REF", table))
    description = (f"digital computed-torque controller with disturbance observer of scenario '{s.name}' "
                   f"({s.controller.sample_rate:g} Hz, observer {s.controller.observer_discretization}, velocity "
                   f"{s.controller.velocity}, delay {s.controller.delay}); exported by dobkit")
    tool = "fmu.controller_export"

    def xml_for(token: str) -> str:
        return controller_description_xml(variables, CONTROLLER_IDENTIFIER, token, sources, description, tool,
                                          stop_time=(ticks - 1) * period, step=period, fmi_version=fmi_version)

    token = instantiation_token("controller", fmi_version, [texts[n] for n in sorted(texts)]
                   + [_config_header(code, variables, _TOKEN_PLACEHOLDER, period, ticks), xml_for(_TOKEN_PLACEHOLDER)])
    texts["controller_config.h"] = _config_header(code, variables, token, period, ticks)
    extra = {"sources/BUILD.txt": _build_txt(fmi_version, sources)}
    if fmi_version == 3:
        extra["sources/buildDescription.xml"] = build_description_xml(CONTROLLER_IDENTIFIER, sources)
    package_fmu(path, xml_for(token), texts, sources, CONTROLLER_IDENTIFIER, fmi_version, extra_files=extra, cc=cc,
                replace=force)
    return path
