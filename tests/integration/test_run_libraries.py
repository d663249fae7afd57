"""What `vrsim run`'s process loads: nothing it does not use. pandas (some 40 MB) would come in through
pyogrio and pyarrow; a big map's run has its memory target to keep (bench/bench_real_rx.py)."""

import subprocess
import sys

from tests.conftest import ROOT


def test_vrsim_run_writes_every_output_without_loading_pandas(tmp_path):
    code = ("import sys\nfrom vrsim.services.cli.main import main\n"
            f"code = main(['run', {ROOT + '/scenarios/quick_rectangle.toml'!r}, '--quiet', '--out', 'out'])\n"
            "print(code, 'pandas' in sys.modules, 'pyogrio' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.stdout.split()[-3:] == ["0", "False", "True"], done.stdout + done.stderr
    for name in ("track.parquet", "as_applied_points.gpkg", "as_applied.tif", "summary.json"):
        assert (tmp_path / "out" / name).is_file(), name
