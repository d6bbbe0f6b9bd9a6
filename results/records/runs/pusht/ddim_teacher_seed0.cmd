OMP_NUM_THREADS=1 .venv/bin/python recipes/pusht/train.py algo=ddim obs=state space=euclidean threads=1 optim.lr=0.001 train.steps=9000 train.max_minutes=60 out_dir=runs/pusht/ddim_teacher_seed0
