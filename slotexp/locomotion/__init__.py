"""Locomotion on the soft legs: periodic tendon gaits, their library, their search and evaluation.

What moves SLOT (DESIGN.md, "Locomotion"): a foot only moves along its leg's
radial line, and winding the tendon both pulls it in and presses it down. With
isotropic Coulomb friction a leg that presses harder than the others sticks while
they slide, so periodic tendon schedules with phase offsets between the legs
translate or turn the body; symmetric ones cancel. A gait here is such a schedule
(:mod:`.primitives`); the library holds one per direction of travel and for
turning (:mod:`.library`), found by a search on the plant itself (:mod:`.openloop`).
"""
