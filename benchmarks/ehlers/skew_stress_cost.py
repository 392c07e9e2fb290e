#!/usr/bin/env python3
"""What the skew stress costs a shear band: one material point in simple shear.

docs/results/regularisation.md, section "Why a large k_sigma does not regularise", derives for a band
normal to x2 (u1,2 = gamma, u2,1 = 0) with the yield function (2.76) and the potential (2.78)
of Scholz (2007), k_mu = alpha = kappa = 0:

* coupled (phi follows the material rotation, phi = -gamma/2): the skew strain, hence the skew
  stress, stays zero and the band traction t1 = sigma12 (t_i = sigma_ij n_j, n = e2; constant
  through the band by sigma12,2 = 0) equals the shear strength T;
* decoupled (phi frozen, the band shear goes into the skew strain eps_skw = (eps12 - eps21)/2,
  which flows plastically): the flow rule (2.79) fixes sigma_skw = r (psi1 / k_sigma) S12
  (r = d eps_skw / d eps_sym12, 1 here) and the yield condition, at the same strength T,
  gives S12 = T / sqrt(1 + r^2 psi1^2 / k_sigma); the traction is
      sigma12 = S12 + sigma_skw = f T,   f = (1 + r psi1/k_sigma) / sqrt(1 + r^2 psi1^2/k_sigma).
  Such a state exists for every k_sigma > 0; it costs the factor f in traction.

This script drives the project's kernel (material_point.MaterialPoint, the same update as the
FE) along both paths from a point consolidated to 100 kPa, for k_sigma = 0.5, 1, 2, 3, 10, 30:

  isotropic  sig11 = sig22 = sig33 = -p held: no normal deviator, Gamma = 1, I constant, the
             setting of the closed form.  Checks, along the path, sigma_skw / S12 against
             r psi1 / k_sigma and sigma12 / T against f, T evaluated independently (numpy,
             eqs 2.76-2.77) from the kernel's hardening variables (beta, delta, epsilon,
             gamma) with F = 0 (rate-independent limit); also the ratio of the two paths'
             peak tractions, which is not at equal strength (their hardening histories
             differ) and shows how far f carries; and a partial path r = 1/psi1, where f
             has its maximum sqrt(1 + 1/k_sigma).
  layer      eps11 = eps33 = 0, sig22 = -p: the kinematics of the softening layer of
             docs/results/regularisation.md (normal deviators, Gamma about 1.2, dilatancy). Peak
             tractions of both paths and the softening of the traction after the peak (what a
             band can gain), for the band-level discussion in the doc.

Prints two tables and writes out/skew_stress_cost/summary.json (or --out). A few seconds.

    PYTHONPATH=. /usr/bin/python3 benchmarks/ehlers/skew_stress_cost.py
"""
import argparse
import math
import os
import time

import numpy as np

from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.local_solver import (S_BETA, S_DELTA, S_EPS_P, S_EPSILON, S_F,
                                                            S_GAMMA, S_LAMBDA)
from cosserat_fenicsx.materials.ehlers.material_point import MaterialPoint, consolidate_state

K_SIGMAS = (0.5, 1.0, 2.0, 3.0, 10.0, 30.0)   # 2: the transition measured in the layer
#: normal control: which of [eps11, eps22, eps33] are stress-controlled (the rest held at 0 strain)
NORMAL = {"isotropic": (True, True, True), "layer": (False, True, False)}


def traction_factor(k_sigma, psi1, r=1.0, lode=1.0):
    """f = sigma12 / T of a plastically flowing state with d eps_skw / d eps_sym12 = r [-].

    T [Pa] is the traction of the coupled state (r = 0) with the same hardening state, pressure,
    normal deviator and Lode factor Gamma = `lode` (2.76, 2.77); r = 1 is the decoupled band
    (phi frozen).  From sigma_skw = r psi1 / k_sigma S12 (flow rule 2.79 with 2.78) and
    Gamma (S12^2 + II_n) + k_sigma sigma_skw^2 = Gamma (T^2 + II_n) (yield 2.76).
    """
    a = r * psi1 / k_sigma
    return (1.0 + a) / math.sqrt(1.0 + k_sigma * a * a / lode)


def shear_strength(stress, state, params):
    """Coupled-equivalent shear strength T [Pa] and Gamma of a state, from (2.76)-(2.77).

    stress: generalised stress (7) [Pa]; state: the kernel's history row (beta, delta [Pa],
    epsilon [Pa], gamma).  With F = 0 (rate-independent limit), sqrt(Phi_F) = kappa - beta I -
    I^2/epsilon; the shear-and-skew part Phi_s = Phi_F - alpha I^2/2 - I^4/delta^2 - k_mu m.m =
    Gamma (S12^2 + II_n) + k_sigma sigma_skw^2, and T = sqrt(Phi_s / Gamma - II_n) is the S12 of
    the state without skew stress on the same surface.  Written here in numpy, independent of
    the Numba kernel that produced the state.
    """
    I = stress[0] + stress[1] + stress[2]
    dev = stress[:3] - I / 3.0
    s12 = 0.5 * (stress[3] + stress[4])
    ii_n = 0.5 * float(dev @ dev)
    ii = ii_n + s12 * s12
    iii = dev[2] * (dev[0] * dev[1] - s12 * s12)
    g = state[S_GAMMA]
    m = 2.0 / 9.0 + math.sqrt(3.0) / (3.0 * g)
    theta = float(np.clip(iii / ii ** 1.5, -2 / (3 * math.sqrt(3)), 2 / (3 * math.sqrt(3)))) if ii > 0 else 0.0
    lode = (1.0 + g * theta) ** m
    root = params.kappa - state[S_BETA] * I - I * I / state[S_EPSILON]
    phi_s = (root * root - 0.5 * params.alpha * I * I - I ** 4 / state[S_DELTA] ** 2
             - params.k_mu * (stress[5] ** 2 + stress[6] ** 2))
    return math.sqrt(max(phi_s / lode - ii_n, 0.0)), lode


def shear_path(material, consolidated, r, normal, gamma_max=1.0, n_steps=400, confining=100e3):
    """Simple shear of a consolidated point to the band shear gamma_max [-] in n_steps.

    The generalised strain (eq 2.49 with u1,2 = gamma, u2,1 = 0, phi = -(1 - r) gamma / 2):
    eps12 = (1 + r) gamma / 2, eps21 = (1 - r) gamma / 2, so eps_sym12 = gamma / 2 and
    eps_skw = r gamma / 2; r = 0 coupled, r = 1 decoupled.  Curvature 0.  Normal components as
    NORMAL[normal] (stresses -confining [Pa], strains 0).  Returns a dict of arrays per step:
    gamma, sig12, sig21, S12, skw (sigma_skw) [Pa], T [Pa], Gamma, F [Pa], Lambda [1/s],
    eps_p_skw [-].
    """
    pt = MaterialPoint(material, consolidated)
    mask = np.array(list(NORMAL[normal]) + [False] * 4)
    rows = []
    for k in range(1, n_steps + 1):
        gamma = gamma_max * k / n_steps
        target = np.zeros(7)
        target[:3] = np.where(mask[:3], -confining, 0.0)
        target[3] = 0.5 * (1.0 + r) * gamma
        target[4] = 0.5 * (1.0 - r) * gamma
        s = pt.advance(mask, target)
        st = pt.state[0]
        T, lode = shear_strength(s, st, material.parameters)
        rows.append((gamma, s[3], s[4], 0.5 * (s[3] + s[4]), 0.5 * (s[3] - s[4]), T, lode, st[S_F],
                     st[S_LAMBDA], 0.5 * (st[S_EPS_P + 3] - st[S_EPS_P + 4])))
    a = np.array(rows)
    names = ("gamma", "sig12", "sig21", "S12", "skw", "T", "Gamma", "F", "Lambda", "eps_p_skw")
    return {n: a[:, i] for i, n in enumerate(names)}


def steady(h, gamma_from=0.05):
    """Mask of the steps past the elastic-plastic transient of the skew stress."""
    return h["gamma"] >= gamma_from


def analyse(k_sigma, gamma_max=1.0, n_steps=400, confining=100e3):
    """Both settings and all paths for one k_sigma; returns the row of the summary."""
    material = EhlersMaterial.hostun(k_sigma=k_sigma)
    psi1 = material.parameters.psi1
    consolidated = consolidate_state(material, -confining)
    f = traction_factor(k_sigma, psi1)
    out = dict(k_sigma=k_sigma, f_closed_form=f, skw_over_S12_closed_form=psi1 / k_sigma,
               f_partial_closed_form=math.sqrt(1.0 + 1.0 / k_sigma))
    # isotropic normal stresses: the setting of the closed form
    c = shear_path(material, consolidated, 0.0, "isotropic", gamma_max, n_steps, confining)
    d = shear_path(material, consolidated, 1.0, "isotropic", gamma_max, n_steps, confining)
    q = shear_path(material, consolidated, 1.0 / psi1, "isotropic", gamma_max, n_steps, confining)
    sc, sd, sq = steady(c), steady(d), steady(q)
    rho = d["skw"][sd] / d["S12"][sd]
    out["iso"] = dict(
        skw_over_S12_min=float(rho.min()), skw_over_S12_max=float(rho.max()),
        coupled_sig12_over_T_max_dev=float(np.abs(c["sig12"][sc] / c["T"][sc] - 1.0).max()),
        decoupled_sig12_over_T_min=float((d["sig12"][sd] / d["T"][sd]).min()),
        decoupled_sig12_over_T_max=float((d["sig12"][sd] / d["T"][sd]).max()),
        partial_sig12_over_T_min=float((q["sig12"][sq] / q["T"][sq]).min()),
        partial_sig12_over_T_max=float((q["sig12"][sq] / q["T"][sq]).max()),
        max_Gamma_dev=float(np.abs(np.concatenate([c["Gamma"], d["Gamma"]]) - 1.0).max()),
        max_overstress_over_T=float((d["F"] / d["T"]).max()),
        decoupled_min_Lambda=float(d["Lambda"][sd].min()),
        decoupled_eps_p_skw_end=float(d["eps_p_skw"][-1]),
        peak_coupled=float(c["sig12"].max()), peak_decoupled=float(d["sig12"].max()),
        gamma_at_peak_coupled=float(c["gamma"][c["sig12"].argmax()]),
        gamma_at_peak_decoupled=float(d["gamma"][d["sig12"].argmax()]),
        peak_ratio=float(d["sig12"].max() / c["sig12"].max()))
    # the layer's kinematics
    c = shear_path(material, consolidated, 0.0, "layer", gamma_max, n_steps, confining)
    d = shear_path(material, consolidated, 1.0, "layer", gamma_max, n_steps, confining)
    sd = steady(d)
    lode_d = d["Gamma"][sd]
    f_lode = np.array([traction_factor(k_sigma, psi1, 1.0, g) for g in lode_d])

    def at(h, g):
        return float(np.interp(g, h["gamma"], h["sig12"]))
    out["layer"] = dict(
        peak_coupled=float(c["sig12"].max()), peak_decoupled=float(d["sig12"].max()),
        gamma_at_peak_coupled=float(c["gamma"][c["sig12"].argmax()]),
        gamma_at_peak_decoupled=float(d["gamma"][d["sig12"].argmax()]),
        peak_ratio=float(d["sig12"].max() / c["sig12"].max()),
        Gamma_at_peak_decoupled=float(d["Gamma"][d["sig12"].argmax()]),
        decoupled_sig12_over_T_over_f_Gamma_max_dev=float(np.abs(d["sig12"][sd] / d["T"][sd] / f_lode - 1.0).max()),
        coupled_softening_0_3=float(c["sig12"].max() / at(c, 0.3)),
        coupled_softening_end=float(c["sig12"].max() / c["sig12"][-1]),
        decoupled_softening_end=float(d["sig12"].max() / d["sig12"][-1]),
        gamma_end=float(c["gamma"][-1]))
    return out


def print_tables(rows):
    print("Isotropic normal stresses (Gamma = 1): kernel against the closed form, steady flow (gamma >= 0.05)")
    print(f"{'k_sigma':>7} | {'psi1/k_s':>8} {'skw/S12 kernel':>17} | {'f':>6} {'sig12/T decoupled':>17} "
          f"| {'peak d/c':>8} | {'sqrt(1+1/k)':>11} {'sig12/T r=1/psi1':>17}")
    for r in rows:
        i = r["iso"]
        print(f"{r['k_sigma']:7.1f} | {r['skw_over_S12_closed_form']:8.4f} {i['skw_over_S12_min']:8.4f}-{i['skw_over_S12_max']:.4f} "
              f"| {r['f_closed_form']:6.4f} {i['decoupled_sig12_over_T_min']:8.4f}-{i['decoupled_sig12_over_T_max']:.4f} "
              f"| {i['peak_ratio']:8.4f} | {r['f_partial_closed_form']:11.4f} "
              f"{i['partial_sig12_over_T_min']:8.4f}-{i['partial_sig12_over_T_max']:.4f}")
    print()
    print("Layer kinematics (eps11 = eps33 = 0, sig22 = -p): peak tractions [kPa] (at gamma) and softening "
          "peak / traction")
    print(f"{'k_sigma':>7} | {'f':>6} | {'coupled peak':>16} {'decoupled peak':>16} {'ratio':>7} | "
          f"{'coupled: @0.3':>13} {'@end':>6} | {'decoupled: @end':>15}")
    for r in rows:
        y = r["layer"]
        print(f"{r['k_sigma']:7.1f} | {r['f_closed_form']:6.4f} | {y['peak_coupled'] / 1e3:7.2f} ({y['gamma_at_peak_coupled']:.3f}) "
              f"{y['peak_decoupled'] / 1e3:7.2f} ({y['gamma_at_peak_decoupled']:.3f}) {y['peak_ratio']:7.4f} | "
              f"{y['coupled_softening_0_3']:13.3f} {y['coupled_softening_end']:6.3f} | {y['decoupled_softening_end']:15.3f}")
    print()
    print("Checks: coupled |sig12/T - 1| (isotropic), Perzyna overstress max F/T, min Lambda of the decoupled path "
          "[1/s], layer: max |sig12 / (f_Gamma T) - 1| with the state's Gamma")
    for r in rows:
        i, y = r["iso"], r["layer"]
        print(f"{r['k_sigma']:7.1f} | {i['coupled_sig12_over_T_max_dev']:.1e} | {i['max_overstress_over_T']:.1e} | "
              f"{i['decoupled_min_Lambda']:.2e} | {y['decoupled_sig12_over_T_over_f_Gamma_max_dev']:.1e}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/skew_stress_cost")
    parser.add_argument("--k-sigma", type=float, nargs="+", default=list(K_SIGMAS))
    parser.add_argument("--gamma-max", type=float, default=1.0, help="band shear at the end [-]")
    parser.add_argument("--steps", type=int, default=400)
    args = parser.parse_args(argv)
    if min(args.k_sigma) <= 0 or args.gamma_max <= 0.05 or args.steps < 20:
        parser.error("k_sigma > 0, gamma_max > 0.05 and steps >= 20 are needed")
    from cosserat_fenicsx.run_guard import RunGuard
    os.makedirs(args.out, exist_ok=True)
    guard = RunGuard(None, os.path.join(args.out, "summary.json"),
                     dict(k_sigma=args.k_sigma, gamma_max=args.gamma_max, steps=args.steps, confining=100e3),
                     label="skew_stress_cost")
    t0 = time.perf_counter()
    rows = []
    for ks in args.k_sigma:
        rows.append(analyse(ks, args.gamma_max, args.steps))
        guard.progress(rows=rows)
    print_tables(rows)
    wall = time.perf_counter() - t0
    print(f"\nwall {wall:.1f} s")
    guard.finish(dict(rows=rows, k_sigma=args.k_sigma, gamma_max=args.gamma_max, steps=args.steps,
                      confining=100e3, psi1=EhlersMaterial.hostun().parameters.psi1, wall_time_s=wall))
    return rows


if __name__ == "__main__":
    main()
