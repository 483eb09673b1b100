"""Check that ParaView reads a run's particles.xmf as written (run by pvpython).

    scripts/check_paraview.sh OUT...     (runs this under xvfb-run if there is no display)
    pvpython --force-offscreen-rendering scripts/check_paraview.py OUT... [--png-dir DIR | --no-picture]

For every run folder OUT, open OUT/particles.xmf with each of ParaView's XDMF readers
(the legacy XDMFReader and both Xdmf3 readers) and check, at every time step, that the
reader loads one point and one vertex cell per particle of the snapshot, every field
array with its number of components, the snapshot's time, and the bounds of its
positions. The sizes come from the .h5 files themselves (h5py if pvpython can import
it, else `h5ls`), not from the XDMF, so a wrong declaration fails too. Then it renders
the last time step to OUT/paraview.png (or DIR/<run>.png), unless --no-picture (the
readers need no window; the picture does). Exit status 1 if any check fails.
"""

import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

from paraview import simple as pv

READERS = {
    "XDMFReader": lambda p: pv.XDMFReader(FileNames=[p]),
    "Xdmf3ReaderS": lambda p: pv.Xdmf3ReaderS(FileName=[p]),
    "Xdmf3ReaderT": lambda p: pv.Xdmf3ReaderT(FileName=[p]),
}
# Datasets that are not point arrays in ParaView: the geometry and the topology.
NOT_ARRAYS = {"position", "connectivity"}

try:
    import h5py
except ImportError:  # pvpython without h5py: fall back on h5ls
    h5py = None


def snapshot(path):
    """time, {dataset: shape}, position bounds (None without h5py) of one .h5 file."""
    if h5py is not None:
        with h5py.File(path, "r") as f:
            shapes = {k: tuple(f[k].shape) for k in f.keys()}
            x = f["position"][...]
            bounds = [(float(x[:, a].min()), float(x[:, a].max())) for a in range(3)] if len(x) else None
            return float(f.attrs["time"]), shapes, bounds
    out = subprocess.run(["h5ls", path], capture_output=True, text=True, check=True).stdout
    shapes = {}
    for line in out.splitlines():
        m = re.match(r"(\S+)\s+Dataset \{([^}]*)\}", line)
        if m:
            shapes[m.group(1)] = tuple(int(d.split("/")[0]) for d in m.group(2).split(","))
    attr = subprocess.run(["h5dump", "-a", "/time", path], capture_output=True, text=True, check=True).stdout
    t = float(re.search(r"\(0\): ([-+0-9.eE]+)", attr).group(1))
    return t, shapes, None


def check_run(out, png):
    """Returns the list of failures for one run folder."""
    fails = []
    xmf = os.path.join(out, "particles.xmf")
    grids = ET.parse(xmf).getroot().find("Domain").find("Grid").findall("Grid")
    snaps = []  # (time, shapes, bounds) in XDMF order
    for g in grids:
        h5 = os.path.join(out, g.get("Name"))
        snaps.append(snapshot(h5))
    if not snaps:
        return [f"{xmf}: no time steps"]
    for name, make in READERS.items():
        r = make(xmf)
        times = list(r.TimestepValues) if len(snaps) > 1 else [snaps[0][0]]
        if len(times) != len(snaps):
            fails.append(f"{name}: {len(times)} time steps, the folder has {len(snaps)} snapshots")
            continue
        for t, (t5, shapes, bounds) in zip(times, snaps):
            where = f"{name} t={t:.6g}"
            if abs(t - t5) > 1e-12 * max(1.0, abs(t5)):
                fails.append(f"{where}: time differs from the file's {t5!r}")
            r.UpdatePipeline(t)
            info = r.GetDataInformation()
            n = shapes["position"][0]
            if info.GetNumberOfPoints() != n or info.GetNumberOfCells() != n:
                fails.append(f"{where}: {info.GetNumberOfPoints()} points, {info.GetNumberOfCells()} cells; the file has {n} particles")
            arrays = {r.PointData[k].Name: r.PointData[k].GetNumberOfComponents() for k in r.PointData.keys()}
            for ds, shape in shapes.items():
                if ds in NOT_ARRAYS:
                    continue
                comps = shape[1] if len(shape) > 1 else 1
                if arrays.get(ds) != comps:
                    fails.append(f"{where}: array {ds} has {arrays.get(ds)} components, the file {comps}")
            if bounds is not None and n > 0:
                b = info.GetBounds()
                for a in range(3):
                    lo, hi = bounds[a]
                    tol = 1e-12 * max(1.0, abs(lo), abs(hi))
                    if abs(b[2 * a] - lo) > tol or abs(b[2 * a + 1] - hi) > tol:
                        fails.append(f"{where}: bounds {b} differ from the positions' {bounds}")
                        break
        print(f"{out}: {name}: {len(times)} time steps checked")
        if name == "Xdmf3ReaderT" and png:
            render(r, times[-1], png)
        pv.Delete(r)
    return fails


def render(r, t, png):
    """The last time step, coloured by velocity (or stress, or rank). The Surface
    representation draws the vertex cells: blank if the reader made none."""
    view = pv.CreateRenderView()
    view.ViewSize = [800, 600]
    view.ViewTime = t
    view.OrientationAxesVisibility = 0
    d = pv.Show(r, view)
    d.SetRepresentationType("Surface")
    d.PointSize = 6
    names = [r.PointData[k].Name for k in r.PointData.keys()]
    field = next((f for f in ("velocity", "stress", "rank") if f in names), None)
    if field:
        pv.ColorBy(d, ("POINTS", field, "Magnitude"))
        d.RescaleTransferFunctionToDataRange(True, False)
        d.SetScalarBarVisibility(view, True)
    view.ResetCamera()
    b = r.GetDataInformation().GetBounds()
    if b[5] > b[4]:  # 3D: look from a corner, not down the z axis
        cam = view.GetActiveCamera()
        cam.Azimuth(35)
        cam.Elevation(25)
        view.ResetCamera()
    pv.SaveScreenshot(png, view, ImageResolution=[800, 600])
    pv.Delete(view)
    print(f"wrote {png}")


def main(argv):
    png_dir = None
    picture = "--no-picture" not in argv
    argv = [a for a in argv if a != "--no-picture"]
    if "--png-dir" in argv:
        i = argv.index("--png-dir")
        png_dir = argv[i + 1]
        del argv[i : i + 2]
    if not argv:
        print(__doc__)
        return 2
    failed = False
    for out in argv:
        out = out.rstrip("/")
        png = os.path.join(png_dir, os.path.basename(out) + ".png") if png_dir else os.path.join(out, "paraview.png")
        png = png if picture else None
        fails = check_run(out, png)
        for f in fails:
            print(f"FAIL {out}: {f}")
        failed |= bool(fails)
        print(f"{out}: {'FAILED' if fails else 'ok'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
