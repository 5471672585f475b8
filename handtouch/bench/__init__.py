"""HT-Bench: any `TactileModel` (handtouch.api) scored on the same items, against reference predictors.

    items.py       each part decoded once: items, inpainting masks, the retrieval reference fixed
    evaluate.py    the tracks scored: retrieval, reconstruction, inpaint, rgb2tactile, prediction
    metrics.py     map metrics: RMSE and contact IoU over a pixel region
    retrieval.py   1-vs-20 tactile retrieval, scored tie-aware and exactly
    ssim.py        batched SSIM in torch (matches skimage's)
    references.py  reference predictors that learn nothing (ZerosModel, CopyLastModel)
    verdicts.py    each trained model's tracks against the reference predictors
    timing.py      contact timing (AUROC over streams with contact), held-out F-RMSE three ways
    examples.py    the predictions figure's windows: most contact, every track's output
    report.py      results JSON, markdown tables, the predictions PNG

May import: what handtouch may, and of handtouch only `api` (the model's public face) and
`config`: the tracks score any model, and the trainer's smoke and comparisons import the bench.
"""
