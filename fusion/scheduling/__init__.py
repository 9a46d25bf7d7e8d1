"""The parts of fusion.scheduler.Scheduler, as mixins: the reorder buffer (``reorder``), the initialisation
(``initialisation``), what is counted and reported (``reporting``) and ``late_policy: replay``
(``replay``). The loop itself is fusion/scheduler.py."""
