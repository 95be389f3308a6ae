"""``hydra/launcher=ray``: the runs of a Hydra multirun as Ray tasks, one run at a time per worker process.

A thin launcher on ``ray.remote`` (:mod:`._core`), configured by :class:`.config.RayLauncherConf`. Ray is the
optional extra ``.[ray]``; it is imported only when a sweep is launched, so Hydra's plugin scan (which imports
this package for every entry point) never needs it.
"""
