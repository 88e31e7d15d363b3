"""The design (Sec. III.A): the LCD design disturbance sets and the design trajectories.

Owns the design sets (:mod:`~ssmobs.design.disturbances`), the LCD distance and its compiled
pair kernel (:mod:`~ssmobs.design.lcd_distance`, :mod:`~ssmobs.design.lcd_native`,
``lcd_kernel/``) and the trajectories simulated from them
(:mod:`~ssmobs.design.trajectories`).

May import: the shared top-level modules, :mod:`ssmobs.models` and :mod:`ssmobs.config` (the
scenario).
"""
