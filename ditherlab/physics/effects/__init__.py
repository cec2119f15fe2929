"""The physical effects a torque model is made of: a pure library of named terms.

The base model is ``tau = tau_grav(q) + J(q)^T F + tau_f + e`` (``docs/method.md``). Each named
effect adds
a torque with a physical form, driven by logged variables, with a few parameters:

=======================  ====================================================  ==================
effect                   torque on joint j (the fitted parameters in bold)     driven by
=======================  ====================================================  ==================
``viscous``              **c** · dq                                            dq
``stribeck``             **(Fs - Fc)** · exp(-(dq / **vs**)²) · sign(dq)        dq (moving)
``load_friction``        **k** · (|L| - L_ref) · sign(dq) while moving, and    L = L0 + **c**(1 +
                         the stick band widened by **k** · (|L| - L_ref)       **g**|L0|/fc)sign(dq);
                                                                               L0 = tau_grav +
                                                                               J^T F (+ M ddq +
                                                                               C dq moving)
``temperature_friction`` **a** · (x - x_ref) · sign(dq) while moving, and the   temp_j, or
                         band widened by **a** · (x - x_ref); x = temperature   exp(-t / **T**)
                         or exp(-t / T) (time since start, **T** fitted)
``position_ripple``      **A** sin(2π q / **P**) + **B** cos(2π q / **P**)        q (P by a spectral
                                                                               search)
``payload``              Y(q) · (**m**, **m c**): gravity of a mass at the tool   q (gravity
                                                                               regressor)
``attenuation_lag``      the servo shows **g** · lag_L(J^T F(t - **d**))       J^T F
                         instead of J^T F(t): a delay **d** or a first-order
                         lag of **L** samples
``dither_extraction``    where the dither is on over a whole window, the        J^T F, dither
                         servo shows **g** · lag_L(mean_W(J^T F)): the          period W
                         extraction's underestimate and lag (L fitted)
``ft_bias``              the sensor reads F + **b**: the true wrench is F - b    F/T columns
``ft_drift``             the sensor reads F + **d** x(t), a warm-up x(t) = (1 -   F/T columns, t
                         exp(-t/**T**)) / (1 - exp(-S/T)) from the first sample
                         (**d**: the drift over the S seconds fitted on)
``inertia``              **s** · (M(q) ddq + C(q, dq) dq)_j + **Jm** · ddq_j     ddq, dq
``drive_gain``           the log reads **k** · tau: (**k** - 1) · (tau_grav +     tau_grav + J^T F
                         J^T F + M ddq + C dq)_j                               (+ M ddq +
                                                                               C dq moving)
``joint_offset``         the arm is at q + **δ**: (∂(tau_grav + J^T F)/∂q ·     q (gravity and
                         **δ**)_j (linearised; one δ per joint, shared)         J^T F derivative)
``ft_frame``             the sensor is turned by **θ** and offset by **d** in   F/T columns, tool
                         the tool frame: the true wrench is F = Q F_log,        orientation
                         m = Q m_log + (R d) × F, Q = R exp([θ]×) R^T
``dynamics``             Y(q, dq, ddq) · **Δπ**: pinocchio's regressor of       q, dq, ddq
                         every link on a base set chosen by pivoted QR
=======================  ====================================================  ==================

Friction-type effects act as a sliding torque only in the ``moving`` regime; while the joint
sticks, friction is whatever lies in the band, so there they can only change the band's width.
Parameters in bold are fitted by least squares on the model's residual (:mod:`ditherlab.physics.effect_fit`;
nonlinear ones — vs, T, P, d — by a search over a grid), per joint, except ``payload``,
``ft_bias``, ``ft_drift``, ``ft_frame`` and ``joint_offset`` whose parameters are shared by all
joints.

The package, bottom up: ``signals`` (the arrays of a recording effects are driven by, with or
without the F/T sensor), ``base`` (the :class:`Effect` interface), one module per family
(``friction``, ``transmission``, ``rigid``, ``sensor``, ``drive``), ``library`` (the registry and the
conversion to and from the model file), ``apply`` (applying a model's effects for every
consumer). It imports nothing above the model: the residual, the fit, identification and
diagnosis are built on it. None of this code is shared with the simulator, whose hidden effects
are written in the plant's own terms.
"""

from ditherlab.physics.effects.apply import (
    check_model_effects,
    effects_torque,
    external_torque,
    force_gain,
    model_text,
    sensor_wrench,
    widening,
)
from ditherlab.physics.effects.base import Design, Effect, design_at, fmt
from ditherlab.physics.effects.drive import DriveGain, JointOffset
from ditherlab.physics.effects.friction import LoadFriction, Stribeck, TemperatureFriction, Viscous
from ditherlab.physics.effects.library import (
    EFFECTS,
    REF_KEYS,
    FitResult,
    clean_none,
    effect_names,
    get_effect,
    hyper_params,
    joint_params,
    make_spec,
    spec_params,
)
from ditherlab.physics.effects.rigid import Dynamics, Inertia, Payload
from ditherlab.physics.effects.sensor import AttenuationLag, FtBias, FtDrift, FtFrame
from ditherlab.physics.effects.signals import Signals, release, signals
from ditherlab.physics.effects.transmission import PositionRipple

__all__ = [
    "EFFECTS",
    "REF_KEYS",
    "AttenuationLag",
    "Design",
    "DriveGain",
    "Dynamics",
    "Effect",
    "FitResult",
    "FtBias",
    "FtDrift",
    "FtFrame",
    "Inertia",
    "JointOffset",
    "LoadFriction",
    "Payload",
    "PositionRipple",
    "Signals",
    "Stribeck",
    "TemperatureFriction",
    "Viscous",
    "check_model_effects",
    "clean_none",
    "design_at",
    "effect_names",
    "effects_torque",
    "external_torque",
    "force_gain",
    "get_effect",
    "hyper_params",
    "joint_params",
    "make_spec",
    "release",
    "model_text",
    "sensor_wrench",
    "signals",
    "spec_params",
    "widening",
    "fmt",
]
