"""Training: typed settings (``settings``), the three-stage schedule (``stages``), how it stops on a
signal (``stopping``), the run folder's layout (``run_folder``), resuming (``resume``), what the
loggers keep and print (``logs``), Lightning callbacks (``callbacks``) and learning-rate schedules
(``lr_schedules``)."""
