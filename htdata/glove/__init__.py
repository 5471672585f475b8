"""The glove model: what a glove's taxels mean and where they land on the canonical hand.

    canonical.py    the canonical hand: places, regions, parts of the 224x224 frame
    layouts.py      glove layouts (schemas/layouts/*.json): blocks of raw cells -> canvas places
    activity.py     which raw cells move (noise + rest wander, contact floor), which only fall (cross-talk)
    commonmode.py   the glove's common-mode wander, taken out before activity judges a cell
    layoutsuggest.py a starting layout from the cells that move in recordings (`htdata layouts suggest`)
    blockcuts.py    rectangular blocks cut from a connected mask of moving cells (for layoutsuggest)
    glovevalue.py   what a glove's value block says: direction, raw-count glove (the one owner of those rules)
    normalise.py    glove units -> [0,1]: the Normaliser that applies a config
    normaliseconfig.py  the normaliser's settings (NormaliseConfig): baselines, floors, defaults, checked once
    baselinefit.py  fitting the per-taxel baseline and noise floor (first frames, or the whole episode)
    normalisesettings.py  a pipeline's [normalise.<layout>] tables over each layout's value block
    restlevel.py    quiet (resting) frames; the per-glove calibration file
    restreference.py  the glove's own rest, pooled over its recordings (`htdata layouts rest`, baseline "shift")
    pooledrest.py   a dataset's pooled glove rest: the one its episodes have, written where a run normalises with it
    contact.py      when a hand is in contact, from its calibration
    rawhealth.py    taxel health from the raw rows, in glove units
    calibration.py  the per-episode calibration a normalisation used, stored with the data
    rasterise.py    taxels -> the 224x224 map, its coverage and regions (and back)
    health.py       per-taxel health (dead, stuck, noisy ...) of one episode
    codecrule.py    which tactile codec a dataset's gloves need (quantisation step vs codec error)
    codecsettings.py  a pipeline's [codec] section: the setting and the codec the rule resolved for a run

May import: htdata's base modules and htdata.format. Nothing about sources, storage or commands.
"""
