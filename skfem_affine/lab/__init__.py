"""The lab: ready-made scenes, measured runs and their figures, and the ``skfem-affine`` command.

A scene (:mod:`.scenes`, or a file, as a :class:`~skfem_affine.lab.scene_spec.SceneSpec`) is run
by one or several methods (:mod:`.methods`); :mod:`.runs` steps them frame by frame in turn and
measures each reduced run against the full-space reference with :mod:`.metrics`; :mod:`.sweep`
(a threshold grid on Dask, each cell in a child process of :mod:`.cells`), :mod:`.scaling` (the
same scene at growing size) and :mod:`.trade` (speed against error, per threshold or per error
budget) repeat that; :mod:`.runners` is their one import for scripts. The results go to tables
(:mod:`.tables`), figures (:mod:`.plots`) and ParaView series (:mod:`.io`, which also loads
meshes); :mod:`.cli` is the command line on top of it all.
"""
