"""From lens prescription to proxy camera: the optics (:mod:`.optics`:
lenses, ray tracer, PSFs, lens files), ISO 12233 SFR (:mod:`.sfr`),
simulated captures (:mod:`.simulate`), the proxy-camera fitter
(:mod:`.fit`), closing the loop (:mod:`.loop`), figures and atomic reports
(:mod:`.report`), ``isp demo`` (:mod:`.demo`) and ``isp calib``
(:mod:`.cli`).

May import: ``isp`` (DNG reading and writing, errors, the executor), numpy,
scipy, OpenCV, colour-science; never ``modules``, ``restoration``,
``export`` or torch.
"""
