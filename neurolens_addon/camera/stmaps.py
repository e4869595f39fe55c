"""A camera's ST-maps and a frame's lens data: core.stmap for the lens of a resolved camera
(camera.LensSetup: the lens as focused and zoomed, its sensor plane, its film), one place for
the render command and the panel's Write ST-Maps.
"""

from __future__ import annotations

from ..core.errors import NeuroLensError
from ..core.prescription import WAVELENGTH_D_NM


def _frame(setup, overscan: float = 1.0):
    from ..core.film import FilmError
    from ..core.stmap import MapFrame
    f = setup.film
    if abs(f.shift_x_mm) > 1e-9 or abs(f.shift_y_mm) > 1e-9:
        raise FilmError("the camera's lens shift moves the frame off the lens's axis; set "
                        "Shift X and Y to 0 for its ST-maps")
    if abs(f.width_mm / f.width_px - f.height_mm / f.height_px) > 1e-9 * f.width_mm:
        raise FilmError("the film's pixels are not square (pixel aspect): ST-maps need "
                        "square pixels")
    try:
        return MapFrame.checked(f.width_px, f.height_px, f.width_mm, overscan)
    except ValueError as exc:
        raise FilmError(str(exc)) from None


def _chief(setup, frame):
    """The chief-ray mapping of a camera's lens over a frame: a prescription's
    (core.stmap.chief_mapping), or a lens known only from a ray table's, through its model
    (camera.table_lens)."""
    if setup.entry.table:
        return setup.lens.chief_ray_table(frame.film_radius_mm)
    from ..core.stmap import chief_mapping
    return chief_mapping(setup.lens, setup.sensor_z_mm, frame, squeeze=setup.squeeze)


def camera_maps(setup, direction: str, overscan: float = 1.0):
    """(map (H, W, 3) float32 R G A rows from the bottom, EXR header, lens data) of a
    camera's `direction` map with the undistorted image `overscan` times the frame; the
    project's error (one line) where the camera has no map."""
    from ..core.stmap import lens_map
    frame = _frame(setup, overscan)
    return lens_map(setup.lens, _chief(setup, frame), frame, direction,
                    focus_mm=setup.focus_mm, sensor_z=setup.sensor_z_mm,
                    wavelength_nm=WAVELENGTH_D_NM)


def frame_lens_data(setup) -> dict:
    """The lens data of a rendered frame (core.stmap.lens_metadata at the camera's lens as
    focused, on its film) with the f-number it rendered at and the model that rendered it; an
    anamorphic lens has no radial distortion model (it says why)."""
    f = setup.film
    base = {"camera": setup.camera, "model": setup.model, "f_number": setup.f_number,
            "focus_distance_mm": setup.focus_mm, "sensor_mm": [f.width_mm, f.height_mm],
            "resolution_px": [f.width_px, f.height_px],
            "shift_mm": [f.shift_x_mm, f.shift_y_mm]}
    try:
        from ..core.stmap import MapFrame, lens_metadata
        frame = MapFrame(f.width_px, f.height_px, f.width_mm)
        table = _chief(setup, frame)
    except NeuroLensError as exc:
        return {**base, "lens": setup.lens.name, "distortion": None,
                "distortion_note": str(exc)}
    meta = lens_metadata(setup.lens, table, frame, focus_mm=setup.focus_mm,
                         sensor_z=setup.sensor_z_mm, wavelength_nm=WAVELENGTH_D_NM)
    return {**meta, **base}
