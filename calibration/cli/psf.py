"""``isp calib psf``: a polychromatic PSF at one field, or the PSF map over the sensor."""

from __future__ import annotations

import argparse

import numpy as np

from isp.cli.arguments import numbers

from calibration.cli.arguments import add_device_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib psf``."""
    p.description = ("Diffraction PSF (Huygens, Debye or FFT) of a sensor channel through "
                     "the camera's spectral response, at one field or over the paper's "
                     "15 x 20 sensor regions (cached on disk).")
    p.epilog = ("examples:\n  isp calib psf e9.json --field 0,25 --channel G --plot psf.png\n"
                "  isp calib psf e9.json --field 20 --wavelength 550 --method huygens\n"
                "  isp calib psf e9.json --map --plot map.png --npz map.npz\n"
                "  isp calib psf e9.json --map --perturb random --seed 7 --plot dev7.png")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("lens")
    p.add_argument("--field", default="0", help="θy or θx,θy in degrees (default 0)")
    p.add_argument("--channel", default="G", help="R, G or B through the camera response (default G)")
    p.add_argument("--wavelength", type=float, help="a single wavelength in nm instead of a channel")
    p.add_argument("--method", choices=("huygens", "debye", "fft"), default="debye")
    p.add_argument("--n", type=int, default=64, help="PSF samples per side")
    p.add_argument("--pupil-samples", type=int, default=64)
    p.add_argument("--map", action="store_true", help="the whole sensor (15 x 20 regions)")
    p.add_argument("--rows", type=int, default=15)
    p.add_argument("--cols", type=int, default=20)
    p.add_argument("--npz", metavar="OUT.npz", help="save the map")
    p.add_argument("--plot", metavar="OUT.png")
    add_device_arguments(p)


def run(args: argparse.Namespace) -> int:
    """One PSF (``--field``) or the map (``--map``) of the lens or a device; print, save, plot."""
    from calibration.optics.io import read_lens
    from calibration.optics.psf.spectral import polychromatic_psf
    from calibration.report import save_figure
    from calibration.simulate.device import device_lens
    from calibration.optics.psf.map import PSFMapSettings, plot_psf_map, psf_map

    lens = read_lens(args.lens)
    model, what = device_lens(lens, args.perturb, args.seed)
    if args.map:
        m = psf_map(model, PSFMapSettings(grid=(args.rows, args.cols), method=args.method, n=args.n,
                                          pupil_samples=args.pupil_samples), cache_dir=args.cache)
        print(f"PSF map {args.rows}x{args.cols}x{len(m.channels)} ({what}), {m.n}x{m.n} samples at "
              f"{m.pitch_um:.3f} µm; cache key {m.key[:12]}")
        if args.npz:
            m.to_npz(args.npz)
            print(f"wrote {args.npz}")
        if args.plot:
            plot_psf_map(m, args.plot, channel=args.channel)
            print(f"wrote {args.plot}")
        return 0
    field = numbers(args.field, 2) if "," in args.field else (0.0, float(args.field))
    response = args.channel if args.wavelength is None else ([args.wavelength], [1.0])
    psf = polychromatic_psf(model, field, response, method=args.method, n=args.n,
                            pupil_samples=args.pupil_samples)
    ee = psf.encircled_energy(2.0 * lens.sensor.pixel_pitch_um) if hasattr(psf, "encircled_energy") else None
    print(f"PSF at field {field} deg ({what}), {args.method}, {psf.data.shape[0]}² at {psf.pitch_um:.3f} µm: "
          f"centroid {tuple(round(v, 3) for v in psf.centroid_um)} µm"
          + (f", energy within 2 px {ee:.3f}" if ee is not None else ""))
    if args.plot:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(4.2, 4.0))
        half = psf.data.shape[0] * psf.pitch_um / 2
        ax.imshow(np.sqrt(psf.data / psf.data.max()), cmap="inferno", extent=(-half, half, half, -half))
        ax.set(xlabel="x (µm)", ylabel="y (µm, down the sensor)",
               title=f"PSF {args.channel if args.wavelength is None else f'{args.wavelength:g} nm'} "
                     f"at {field} deg (sqrt scale)")
        save_figure(fig, args.plot)
        print(f"wrote {args.plot}")
    return 0
