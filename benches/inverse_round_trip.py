"""Round trip of the inverse map: inverse(forward(x)) - x for random voxels of a run.

    python benches/inverse_round_trip.py RUN N HARMAP

Forward is the run's own map: (u, theta, psi) at the voxel (u = 1 - phi, RUN/u/0).
Writes /tmp/inv_in.csv, runs `HARMAP inverse RUN --points /tmp/inv_in.csv -o
/tmp/inv_out.csv`, and prints the distance quantiles in voxels. Map RUN with
`harmap map RUN --exact` for the reference forward map.
"""
import sys, numpy as np, zarr, subprocess, csv
run=sys.argv[1]; n=int(sys.argv[2]); H=sys.argv[3]
g=zarr.open_group(run,mode='r'); a=g.attrs['harmap']; gr=a['grid']
phi=np.asarray(g['u/0']); th=np.asarray(g['theta/0']); ps=np.asarray(g['psi/0']); lab=np.asarray(g['labels/0'])
z,y,x=np.nonzero(np.isin(lab,[1,2]) & np.isfinite(th))
rng=np.random.default_rng(1); k=rng.choice(len(z),min(n,len(z)),replace=False)
org=np.array(gr['origin']); h=gr['spacing']
with open('/tmp/inv_in.csv','w') as f:
    f.write('u,theta,psi\n')
    for i in k: f.write('%r,%r,%r\n'%(float(phi[z[i],y[i],x[i]]),float(th[z[i],y[i],x[i]]),float(ps[z[i],y[i],x[i]])))
subprocess.run([H,'inverse',run,'--points','/tmp/inv_in.csv','-o','/tmp/inv_out.csv','--progress','never'],check=True)
rows=list(csv.DictReader(open('/tmp/inv_out.csv')))
err=[];bad=0
for i,r in zip(k,rows):
    if r['status']!='ok': bad+=1; continue
    p=(np.array([float(r['x']),float(r['y']),float(r['z'])])-org)/h
    err.append(np.linalg.norm(p-np.array([x[i],y[i],z[i]])))
err=np.array(err)
print("rows",len(rows),"failed",bad,"median %.3f p90 %.3f p99 %.3f max %.2f voxels"%tuple(np.percentile(err,[50,90,99,100])))
