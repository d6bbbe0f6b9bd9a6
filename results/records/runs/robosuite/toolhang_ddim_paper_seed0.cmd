OMP_NUM_THREADS=1 MUJOCO_GL=egl .venv/bin/python recipes/robosuite/train.py task=ToolHang algo=ddim threads=1 train.max_minutes=57 seed=0 out_dir=runs/robosuite/toolhang_ddim_paper_seed0
