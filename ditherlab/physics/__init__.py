"""The physics of the torque model: the dither and its extraction (:mod:`.dither`), the
band-plus-noise likelihood and its fits (:mod:`.band_fit`), the library of named effects
(:mod:`.effects`), the band-aware residual and its noise floor (:mod:`.residual`) and the stacked
least squares that fits an effect to it (:mod:`.effect_fit`).

Arrays and data types in, arrays out: nothing here reads or writes a file.
"""
