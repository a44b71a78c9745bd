"""The attack of Chelani et al. (CVPR 2023): place an object from server poses and decide its presence.

Modules: :mod:`.align` (Alg. 1, Sim(3), robust and pivot aligners, registered by name), :mod:`.presence`
(eps⁺/eps⁻ rule, leave-one-scene-out), :mod:`.local_model` (the attacker's local poses: oracle or pycolmap SfM),
:mod:`.run` (one attack from frame-keyed pose dicts).
"""
