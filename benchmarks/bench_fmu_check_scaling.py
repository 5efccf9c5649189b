"""Cost of ``fmu.check_fmu`` against the number of variables in the model description.

The test FMU ``gain`` (tests/fmu_models) is packaged with N extra real parameters, so the description
grows (about 120 bytes per variable) while the model stays the same; the check's runs cost the same
at every N.  fmpy's own parse of the description (``read_model_description``) is timed beside it:
the check parses it once, so the difference is dobkit's share.  CPU seconds, best of the repeats:

    PYTHONPATH=.:tests python benchmarks/bench_fmu_check_scaling.py [--sizes 2000,20000,200000] [--repeats 2]
"""
from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from pathlib import Path


def package(n: int, folder: Path) -> Path:
    from fmu_models import build

    def edit(xml: str) -> str:
        extra = "".join(f'    <ScalarVariable name="p{i}" valueReference="{100 + i}" causality="parameter" '
                        f'variability="fixed" initial="exact"><Real start="1"/></ScalarVariable>\n' for i in range(n))
        return xml.replace("  </ModelVariables>", extra + "  </ModelVariables>")

    return build("gain", folder, xml_edit=edit, filename=f"gain_{n}")


def cpu(fn) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="2000,20000,200000", help="extra variables, comma separated")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    from fmpy import read_model_description

    from fmu import check_fmu, extract_fmu
    print(f"{'variables':>10} {'XML MB':>6} {'check (s)':>10} {'fmpy parse (s)':>15} {'check per variable (us)':>24}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(s) for s in args.sizes.split(",")):
            path = package(n, Path(tmp))
            check = min(cpu(lambda: check_fmu(path)) for _ in range(args.repeats))
            with extract_fmu(path) as ex:
                parse = min(cpu(lambda: read_model_description(str(ex.root), validate=False))
                            for _ in range(args.repeats))
            size = zipfile.ZipFile(path).getinfo("modelDescription.xml").file_size
            print(f"{n:>10} {size / 1e6:>6.2f} {check:>10.2f} {parse:>15.2f} {1e6 * check / n:>24.0f}")


if __name__ == "__main__":
    main()
