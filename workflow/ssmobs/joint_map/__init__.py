"""The joint MAP per design trajectory and its checks (Sec. III.B).

Owns the driver and its summary over K^max (:mod:`~ssmobs.joint_map.driver`), the settings
(:mod:`~ssmobs.joint_map.settings`), the log-barrier Newton solver
(:mod:`~ssmobs.joint_map.barrier`), the checks of a found maximum
(:mod:`~ssmobs.joint_map.checks`) and the multi-start search
(:mod:`~ssmobs.joint_map.multi_start`).

May import: the shared top-level modules and :mod:`ssmobs.models`.
"""
