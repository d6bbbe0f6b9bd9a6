OMP_NUM_THREADS=1 MUJOCO_GL=egl .venv/bin/python recipes/robosuite/train.py task=Lift algo=srfmp threads=1 train.max_minutes=45 seed=0 out_dir=runs/robosuite/lift_srfmp_paper_seed0
