"""``isp calib simulate``: a simulated slanted-square chart capture, written as a DNG."""

from __future__ import annotations

import argparse

from isp.cli.arguments import numbers

from calibration.cli.arguments import add_device_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib simulate``."""
    p.description = ("Render a slanted-square chart (one square per PSF region) through the "
                     "lens's PSF map, with relative illumination, Bayer sampling, "
                     "Poisson-Gaussian noise and GainMap lens-shading opcodes, and write "
                     "it as a DNG that `isp process` and `isp calib sfr` read like a real "
                     "capture.")
    p.epilog = ("examples:\n  isp calib simulate e9.json -o nominal.dng --size 2000,1500\n"
                "  isp calib simulate e9.json -o dev3.dng --perturb random --seed 3\n"
                "  isp calib simulate e9.json -o dev3.dng --perturb random --seed 3 --save-lens dev3.json\n"
                "  isp calib simulate e9.json -o tilted.dng --perturb random --seed 3 --sensor-tilt 0,0.2"
                "   # the sensor tilted 0.2° about y\n"
                "  isp calib simulate e9.json -o scene.dng --perturb random --seed 3 --device dev3/device.json"
                "   # the capture carries its module's calibration")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("lens")
    p.add_argument("-o", "--output", required=True, help="output .dng")
    p.add_argument("--size", metavar="W,H", help="sensor size in pixels (keeps the sensor's width in mm)")
    p.add_argument("--pixel-pitch", type=float, metavar="UM", help="pixel pitch in µm")
    p.add_argument("--exposure", type=float, default=0.8, help="white level reached by the chart's white")
    p.add_argument("--colorchecker", action="store_true", help="add ColorChecker patches in the middle")
    p.add_argument("--save-lens", metavar="FILE.json",
                   help="also write the device's true lens (the prescription with the device's perturbation, "
                        "a proxy lens file), to score a correction or a fit against")
    p.add_argument("--device", metavar="FILE",
                   help="a device calibration (device/v1) the DNG carries in DNGPrivateData, as a calibrated "
                        "module's captures would: `isp process` then corrects it with that calibration")
    sensor = p.add_argument_group("the sensor's surface", "where the sensor lies off the lens's image plane "
                                  "(+: away from the lens); each PSF region is computed on it, so its blur is "
                                  "the lens's own defocus there")
    sensor.add_argument("--focus-shift", type=float, metavar="UM", help="the whole sensor moved by UM µm")
    sensor.add_argument("--sensor-tilt", metavar="X,Y", help="the sensor tilted X° about x and Y° about y")
    sensor.add_argument("--field-curvature", type=float, metavar="UM",
                        help="a sensor curved by UM µm at the corner (∝ r²)")
    add_device_arguments(p)


def surface_injections(args) -> list:
    """The ``"optics"`` injections of ``--focus-shift``, ``--sensor-tilt``
    and ``--field-curvature`` (:mod:`calibration.simulate.injected`)."""
    from calibration.simulate.injected import make_injection

    out = []
    if args.focus_shift:
        out.append(make_injection("focus_shift", dz_um=args.focus_shift))
    if args.sensor_tilt:
        tx, ty = numbers(args.sensor_tilt, 2)
        out.append(make_injection("sensor_tilt", tilt_x_deg=tx, tilt_y_deg=ty))
    if args.field_curvature:
        out.append(make_injection("field_curvature", dz_corner_um=args.field_curvature))
    return out


def run(args: argparse.Namespace) -> int:
    """Simulate the capture through the lens or a device and write the DNG."""
    from calibration.simulate.capture import simulate_capture, write_capture
    from calibration.optics.io import read_lens
    from calibration.simulate.chart import slanted_square_chart
    from calibration.simulate.device import device_lens

    surface = surface_injections(args)       # a bad value fails before the render
    carried = ""
    if args.device:
        from isp.io.device import DeviceCalibration

        carried = DeviceCalibration.load(args.device).to_text()   # a bad file fails before the render
    lens = given = read_lens(args.lens)
    if args.pixel_pitch or args.size:
        from calibration.optics.lens import Sensor

        w, h = (numbers(args.size, 2) if args.size else (lens.sensor.width_px, lens.sensor.height_px))
        pitch = args.pixel_pitch or lens.sensor.pixel_pitch_um * lens.sensor.width_px / w
        lens = lens.replace(sensor=Sensor(pixel_pitch_um=pitch, width_px=int(w), height_px=int(h)))
    model, what = device_lens(lens, args.perturb, args.seed)
    sensor = lens.sensor
    chart = slanted_square_chart(sensor.height_px, sensor.width_px, colorchecker=args.colorchecker)
    capture = simulate_capture(model, chart, exposure=args.exposure, rng=args.seed, injections=surface,
                               psf_map_options={"cache_dir": args.cache} if args.cache else None)
    if surface:
        what += ", sensor " + "; ".join(f"{i.effect} " + ", ".join(f"{k} {v:g}" for k, v in i.params.items())
                                        for i in surface)
    if carried:
        capture = (capture[0], capture[1].replace(device_calibration=carried))
    out = write_capture(args.output, capture=capture)
    print(f"wrote {out}: {sensor.width_px}x{sensor.height_px} at {sensor.pixel_pitch_um:.3f} µm, {what}; "
          f"process it with `isp process {out} -o capture.jpg`, measure it with "
          f"`isp calib sfr {out} --roi ...`")
    if args.save_lens:
        from calibration.fit.proxy import save_proxy

        # the prescription's own sensor: --size and --pixel-pitch set the capture, not the lens
        path = save_proxy(args.save_lens, given, getattr(model, "perturbation", None))
        print(f"wrote {path}: the device's true lens (a proxy lens file: `isp eval --lens {path} "
              f"--samples 0 --with-proxy` scores a correction on this device)")
    return 0
