"""Baselines from other papers, re-implemented from their descriptions (no code copied).

- nerf2: a NeRF2-style neural radio field (Zhao et al., MobiCom 2023) for RSSI prediction.
"""
