"""`posedesc render` as a user runs it: a real subprocess."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from index.viewpoints import hemisphere


def posedesc(*args: str) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "posedesc"  # the console script, as a user runs it
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=300)


def test_render_writes_templates_and_sheet(tmp_path, l_shape):
    mesh = tmp_path / "shape.ply"
    mesh.write_bytes(l_shape.export(file_type="ply"))
    r = posedesc("render", str(mesh), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    entries = json.loads((tmp_path / "out" / "templates.json").read_text())
    assert len(entries) == 301 and set(entries[0]) == {"azimuth", "elevation", "inplane"}
    assert all(e["inplane"] == 0 for e in entries)
    sheet = cv2.imread(str(tmp_path / "out" / "sheet.png"))
    assert sheet.shape[1] == 25 * 64 and sheet.shape[0] >= 13 * 128


def test_render_real_mesh_noisy_with_inplane(tmp_path, lmo):
    mesh = sorted((lmo / "models").glob("*.ply"))[0]
    r = posedesc(
        "render", str(mesh), "--out", str(tmp_path), "--level", "2", "--inplane-step", "30", "--noisy"
    )
    assert r.returncode == 0, r.stderr
    entries = json.loads((tmp_path / "templates.json").read_text())
    assert len(entries) == len(hemisphere(2)) * 3 and {e["inplane"] for e in entries} == {-30, 0, 30}


@pytest.mark.parametrize(
    "content,suffix,message",
    [(b"hello", ".ply", "not a readable"), (b"x", ".txt", "unsupported mesh format")],
)
def test_render_bad_input_is_one_line(tmp_path, content, suffix, message):
    f = tmp_path / f"bad{suffix}"
    f.write_bytes(content)
    r = posedesc("render", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("units,scale", [("cm", 0.1), ("m", 0.001)])
def test_render_refuses_a_mesh_in_other_units(tmp_path, l_shape, units, scale):
    small = l_shape.copy()
    small.apply_scale(scale)  # in cm or m, rendered as mm: a speck, or 301 black templates
    f = tmp_path / "m.ply"
    f.write_bytes(small.export(file_type="ply"))
    r = posedesc("render", str(f), "--out", str(tmp_path / "o"), "--level", "1")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert "too small for the 200 mm patch window" in r.stderr and f" {units} it is " in r.stderr
    assert not (tmp_path / "o").exists()  # nothing written
    r = posedesc("render", str(f), "--out", str(tmp_path / "o"), "--level", "1", "--units", units)
    assert r.returncode == 0, r.stderr


def test_render_refuses_an_object_no_template_shows(tmp_path, l_shape):
    away = l_shape.copy()
    away.apply_translation([3000.0, 0.0, 0.0])  # its size fits, but the camera looks at its far-off origin
    f = tmp_path / "away.ply"
    f.write_bytes(away.export(file_type="ply"))
    r = posedesc("render", str(f), "--out", str(tmp_path / "o"), "--level", "1")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "invisible in every template" in r.stderr and not (tmp_path / "o").exists()
