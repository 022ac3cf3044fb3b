"""The `isp synth` command (restoration/cli/synth.py): help, and a missing
lens or latent folder is one line and exit 2.

Kind: property.
"""

from __future__ import annotations

import pytest

from isp.cli.main import main

pytestmark = pytest.mark.property


def test_synth_help_and_errors(capsys, tmp_path, e9_zmx):
    with pytest.raises(SystemExit) as e:
        main(["synth", "--help"])
    assert e.value.code == 0
    assert "isp synth --lens" in capsys.readouterr().out
    assert main(["synth", "--lens", str(tmp_path / "no.zmx"), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no.zmx" in err and len(err.strip().splitlines()) == 1
    # data:REST names a file of the shared data folder, as in a training config
    assert main(["synth", "--lens", "data:lenses/phone/no.zmx", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "lenses/phone/no.zmx: no such lens file" in err and "data:" not in err
    zmx = e9_zmx
    assert main(["synth", "--lens", "data:lenses/phone/" + zmx.name, "-o", str(tmp_path / "o"),
                 "--latent", str(tmp_path / "none")]) == 2
    assert "latent" in capsys.readouterr().err          # found the lens, then stopped at the latents
    assert main(["synth", "--lens", str(zmx), "-o", str(tmp_path / "o"), "--latent", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "latent" in err and len(err.strip().splitlines()) == 1
