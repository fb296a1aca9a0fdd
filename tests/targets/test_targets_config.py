import subprocess
import sys
from dataclasses import dataclass, field

import pytest
import torch

from cotrain.config import ConfigError, load_config
from cotrain.targets import Checkerboard, TargetConfig


def test_default_board_ids_and_points():
    b = Checkerboard()
    assert b.n_corners == 54
    P = b.points()
    # id = j * 9 + i at ((i + 1) s, (j + 1) s, 0)
    for i, j in [(0, 0), (8, 0), (0, 5), (4, 3), (8, 5)]:
        assert torch.allclose(P[j * 9 + i], torch.tensor([(i + 1) * 0.04, (j + 1) * 0.04, 0.0], dtype=torch.float64))


def test_colours_around_corner_zero():
    b = Checkerboard()
    s = 0.04
    c = b.points()[0, :2].float()
    d = s / 4
    offs = torch.tensor([[-d, -d], [d, -d], [-d, d], [d, d]])
    val, cover = b.intensity(c + offs)
    # Square (0, 0) towards the origin is black; (1, 0) and (0, 1) white; (1, 1) black.
    assert val.tolist() == [0.0, 1.0, 1.0, 0.0]
    assert bool((cover == 1).all())
    # The margin is white, and off the board the coverage is 0.
    v, c2 = b.intensity(torch.tensor([[-0.01, 0.1], [1.0, 1.0]]))
    assert v[0] == 1.0 and c2[0] == 1.0 and c2[1] == 0.0


def test_area_filter_keeps_corner_at_saddle():
    b = Checkerboard()
    foot = torch.full((1, 2), 0.01)
    v, _ = b.intensity(torch.tensor([[0.04, 0.04]]), foot)
    assert v.item() == pytest.approx(0.5)


def test_other_board_size():
    b = Checkerboard(TargetConfig(squares_x=7, squares_y=5, square_size=0.03))
    assert b.n_corners == 24 and b.points()[-1, 0].item() == pytest.approx(6 * 0.03)


@dataclass
class Inner:
    a: int = 1  # an int
    b: float = 2.0  # a float


@dataclass
class Outer:
    inner: Inner = field(default_factory=Inner)
    name: str = "x"
    sizes: list[int] = field(default_factory=lambda: [1, 2])


def test_config_yaml_and_overrides(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("inner:\n  a: 5\nname: hello\n")
    cfg = load_config(Outer, p, ["inner.b=3", "sizes=[4, 5]"])
    assert cfg.inner.a == 5 and cfg.inner.b == 3.0 and cfg.name == "hello" and cfg.sizes == [4, 5]


@pytest.mark.parametrize(
    "override,msg",
    [
        ("inner.c=1", "inner.c: unknown key"),
        ("inner.a=abc", "inner.a: expected an integer"),
        ("nokey", "key=value"),
        ("sizes=[1, x]", r"sizes\[1\]"),
    ],
)
def test_config_errors_name_the_key(override, msg):
    with pytest.raises(ConfigError, match=msg):
        load_config(Outer, None, [override])


def test_bad_config_cli_one_line_nonzero(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("height: [unclosed\n")
    for args in (["--config", str(bad)], ["widht=3"], ["--config", str(tmp_path / "missing.yaml")]):
        r = subprocess.run(
            [sys.executable, "-m", "cotrain.cli", "render-preview", "--n", "1", "--out", str(tmp_path / "p.png"), *args],
            capture_output=True,
            text=True,
        )
        assert r.returncode == 2
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
