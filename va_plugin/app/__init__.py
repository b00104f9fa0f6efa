"""``va-app``: a local web page that turns a dropped generator output into a textured mesh.

The page takes a SyncDreamer strip, a Zero123++ grid, or a zip of a Wonder3D or ``transforms.json``
folder; it shows the detected format, the training views and their masks before any training
(:mod:`va_plugin.app.uploads`), trains with live progress and preview renders, and ends with the textured
mesh in an orbitable viewer, the turntable video and the mesh files to download (:mod:`va_plugin.app.server`,
built on Gradio). Each job runs :func:`va_plugin.api.reconstruct` in a child process
(:mod:`va_plugin.app.jobs`): Cancel sends it SIGINT, and it stops with a checkpoint that Resume (or
``va-recon ... --resume``) continues. Only :mod:`va_plugin.app.server` imports Gradio.
"""
