"""Measuring a family: the fidelity metrics against ground truth and the teacher (:mod:`.fidelity`)
and the evaluation of transfer methods on the test shapes (:mod:`.evaluate`)."""
